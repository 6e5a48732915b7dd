#!/usr/bin/env bash
# LeRobot's SmolVLA from nothing, on a CPU: expert demonstrations written as a LeRobotDataset, a SmolVLA teacher
# trained by flow matching (LeRobot's SmolVLAPolicy over a small SmolVLM written locally), its SnapFlow student,
# then teacher 10-NFE, naive 1-NFE and SnapFlow 1-NFE closed loop on the benchmark's evaluation variations with
# offline metrics and batch-1 latency. BENCH picks the benchmark: mt10 (Meta-World MT10, state and one camera;
# docs/results/lerobot-smolvla-mt10/) or libero (two LIBERO-Spatial tasks, 8-D state and two cameras, evaluated on
# LIBERO's fixed initial states by snapflow's evaluator and again by LeRobot's own LIBERO environment).
#
#   bash scripts/lerobot-smolvla.sh [OUTPUT]              # default outputs/lerobot-smolvla-$BENCH
#   BENCH=libero bash scripts/lerobot-smolvla.sh [OUTPUT]
#   SHORT=1 bash scripts/lerobot-smolvla.sh OUTPUT        # two tasks, a tiny SmolVLA, a few steps: the chain only
#   THREADS=1 ...                                         # torch threads, where other jobs share the cores
#
# Run it again after an interruption: finished stages are kept, training resumes from its last checkpoint.
set -euo pipefail
bench="${BENCH:-mt10}"
out="${1:-outputs/lerobot-smolvla-$bench}"
options=(${THREADS:+--threads "$THREADS"})
[ -t 2 ] || options+=(--no-progress)
case "$bench" in
    mt10) env=metaworld tasks=mt10 short_tasks=reach-v3,button-press-topdown-v3 ;;
    libero) env=libero tasks=libero_spatial_0,libero_spatial_1 short_tasks=libero_spatial_0 ;;
    *) echo "BENCH must be mt10 or libero, got $bench" >&2; exit 2 ;;
esac
if [ "${SHORT:-0}" = 1 ]; then
    tasks=$short_tasks demos=2 image=32 size=tiny
    teacher=(--steps 4 --batch-size 4 --checkpoint-every 2) student=(--steps 2 --batch-size 4) episodes=1
elif [ "$bench" = libero ]; then
    demos=20 image=64 size=small episodes=10  # the paper's 10 initial states per task
    teacher=(--steps 1000 --batch-size 32 --learning-rate 3e-4 --checkpoint-every 250)
    student=(--steps 300 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 100)
else
    demos=30 image=64 size=small episodes=20
    teacher=(--steps 5000 --batch-size 32 --learning-rate 3e-4 --checkpoint-every 500)
    student=(--steps 2000 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 500)
fi

[ -f "$out/lerobot/meta/info.json" ] || {
    rm -rf "$out/data"  # an interrupted collection saved nothing; start it again
    snapflow collect --env "$env" --tasks "$tasks" --episodes "$demos" --image-size "$image" --output "$out/data" \
        --lerobot-dataset "$out/lerobot" "${options[@]}"
}
[ -f "$out/teacher/lerobot_policy/snapflow.json" ] ||
    snapflow train --policy-type smolvla --smolvlm "$size" --image-size "$image" --dataset "$out/lerobot" \
        --output "$out/teacher" --resume "${teacher[@]}" "${options[@]}"
[ -f "$out/student/lerobot_policy/snapflow.json" ] ||
    snapflow distill --policy "$out/teacher/lerobot_policy" --dataset "$out/lerobot" --recipe snapflow \
        --output "$out/student" --resume "${student[@]}" "${options[@]}"
[ -f "$out/eval/report.json" ] ||
    snapflow eval --policy "$out/teacher/lerobot_policy=teacher-10,naive" "$out/student/lerobot_policy=snapflow-1" \
        --env "$env" --tasks "$tasks" --episodes "$episodes" --data "$out/data" --output "$out/eval" "${options[@]}"
if [ "$bench" = libero ]; then
    # the student again, in LeRobot's own LIBERO environment, on the same initial states: one environment per
    # episode (LeRobot's environment k starts from initial state k, and moves on by itself after a success), one
    # task at a time (a LIBERO environment with cameras holds ~850 MB)
    for task in ${tasks//,/ }; do
        [ -f "$out/lerobot-eval/$task/report.json" ] ||
            snapflow eval --lerobot-env libero --env-task "$task" --policy "$out/student/lerobot_policy" \
                --modes snapflow-1 --episodes "$episodes" --n-envs "$episodes" --n-action-steps 4 \
                --output "$out/lerobot-eval/$task" "${options[@]}"
    done
fi
