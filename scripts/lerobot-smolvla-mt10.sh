#!/usr/bin/env bash
# LeRobot's SmolVLA on Meta-World MT10 from nothing, on a CPU: expert demonstrations written as a LeRobotDataset,
# a SmolVLA teacher trained by flow matching (LeRobot's SmolVLAPolicy over a small SmolVLM written locally), its
# SnapFlow student, then teacher 10-NFE, naive 1-NFE and SnapFlow 1-NFE closed loop on MT10's evaluation
# variations with offline metrics and batch-1 latency (docs/results/lerobot-smolvla-mt10/).
#
#   bash scripts/lerobot-smolvla-mt10.sh [OUTPUT]        # default outputs/lerobot-smolvla-mt10
#   SHORT=1 bash scripts/lerobot-smolvla-mt10.sh OUTPUT  # two tasks, a tiny SmolVLA, a few steps: the chain only
#   THREADS=1 ...                                        # torch threads, where other jobs share the cores
#
# Run it again after an interruption: finished stages are kept, training resumes from its last checkpoint.
set -euo pipefail
out="${1:-outputs/lerobot-smolvla-mt10}"
options=(${THREADS:+--threads "$THREADS"})
[ -t 2 ] || options+=(--no-progress)
if [ "${SHORT:-0}" = 1 ]; then
    tasks=reach-v3,button-press-topdown-v3 demos=2 image=32 size=tiny
    teacher=(--steps 4 --batch-size 4 --checkpoint-every 2) student=(--steps 2 --batch-size 4) episodes=1
else
    tasks=mt10 demos=30 image=64 size=small
    teacher=(--steps 5000 --batch-size 32 --learning-rate 3e-4 --checkpoint-every 500)
    student=(--steps 2000 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 500)
    episodes=20
fi

[ -f "$out/lerobot/meta/info.json" ] || {
    rm -rf "$out/data"  # an interrupted collection saved nothing; start it again
    snapflow collect --tasks "$tasks" --episodes "$demos" --image-size "$image" --output "$out/data" \
        --lerobot-dataset "$out/lerobot" "${options[@]}"
}
[ -f "$out/teacher/lerobot_policy/snapflow.json" ] ||
    snapflow train --policy smolvla --smolvlm "$size" --image-size "$image" --dataset "$out/lerobot" \
        --output "$out/teacher" --resume "${teacher[@]}" "${options[@]}"
[ -f "$out/student/lerobot_policy/snapflow.json" ] ||
    snapflow distill --policy "$out/teacher/lerobot_policy" --dataset "$out/lerobot" --recipe snapflow \
        --output "$out/student" --resume "${student[@]}" "${options[@]}"
snapflow eval --policy "$out/teacher/lerobot_policy=teacher-10,naive" "$out/student/lerobot_policy=snapflow-1" \
    --tasks "$tasks" --episodes "$episodes" --data "$out/data" \
    --output "$out/eval" "${options[@]}"
