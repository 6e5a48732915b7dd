#!/usr/bin/env bash
# LeRobot's SmolVLA from nothing, on a CPU: expert demonstrations written as a LeRobotDataset, a SmolVLA teacher
# trained by flow matching (LeRobot's SmolVLAPolicy over a small SmolVLM written locally), its SnapFlow student,
# then teacher 10-NFE, naive 1-NFE and SnapFlow 1-NFE closed loop on the benchmark's evaluation variations with
# offline metrics and batch-1 latency. BENCH picks the benchmark: mt10 (Meta-World MT10, state and one camera;
# docs/results/lerobot-smolvla-mt10/) or libero (LIBERO-Spatial's ten tasks, 8-D state and two 128-px cameras,
# evaluated on LIBERO's first 10 fixed initial states a task by snapflow's evaluator and again in LeRobot's own LIBERO
# environment: by LeRobot's lerobot-eval where LeRobot loads snapflow's plugin policies (lerobot >= 0.5), else by
# snapflow eval --lerobot-env).
#
#   bash scripts/lerobot-smolvla.sh [OUTPUT]              # default outputs/lerobot-smolvla-$BENCH
#   BENCH=libero bash scripts/lerobot-smolvla.sh [OUTPUT]
#   DATA=DIR ...                                          # demonstrations already collected with the same settings
#                                                         # (a sweep's data folder): written as the dataset, not collected
#   SHORT=1 bash scripts/lerobot-smolvla.sh OUTPUT        # one or two tasks (one or two demonstrations each), a
#                                                         # tiny SmolVLA, a few steps, episodes cut at 10 steps:
#                                                         # the chain only
#   THREADS=1 ...                                         # torch threads, where other jobs share the cores
#   KEEP=DIR ...                                          # keep the teacher's and the student's latest checkpoints
#                                                         # in DIR/teacher and DIR/student (to commit): another
#                                                         # machine's run continues from them
#   DART=1 ...                                            # libero: demonstrations with noise 0.1 on the executed
#                                                         # actions (both cameras), a 20,000-step teacher with a
#                                                         # weight average: what took MiniVLA's teacher to 89%
#   SEED=N ...                                            # the training seed (default 0); another seed's teacher
#                                                         # and student go to teacher-seedN/ and student-seedN/
#
# Run it again after an interruption: finished stages are kept, training resumes from its last checkpoint and the
# evaluation from its last finished wave of episodes.
set -euo pipefail
bench="${BENCH:-mt10}"
out="${1:-outputs/lerobot-smolvla-$bench}"
options=(${THREADS:+--threads "$THREADS"})
[ -t 2 ] || options+=(--no-progress)
case "$bench" in
    mt10) env=metaworld tasks=mt10 short_tasks=reach-v3,button-press-topdown-v3 short_demos=2 ;;
    libero) env=libero tasks=libero_spatial short_tasks=libero_spatial_0 short_demos=1 ;;  # ~140 steps a demonstration
    *) echo "BENCH must be mt10 or libero, got $bench" >&2; exit 2 ;;
esac
collect=() max_steps=
if [ "${SHORT:-0}" = 1 ]; then
    tasks=$short_tasks demos=$short_demos image=32 seen=32 size=tiny max_steps=10
    teacher=(--steps 4 --batch-size 4 --checkpoint-every 2) student=(--steps 2 --batch-size 4) episodes=1
elif [ "$bench" = libero ] && [ "${DART:-0}" = 1 ]; then
    # DART demonstrations (as libero-spatial-dart.toml's, with the wrist camera too), four times the budget
    demos=50 image=128 seen=64 size=small episodes=10 collect=(--action-noise 0.1)
    teacher=(--steps 20000 --batch-size 32 --learning-rate 3e-4 --ema-decay 0.999 --checkpoint-every 500)
    student=(--steps 2000 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 500)
elif [ "$bench" = libero ]; then
    # the LIBERO sweeps' demonstrations (128 px), which SmolVLA reads at 64; the paper's 10 initial states a task
    demos=50 image=128 seen=64 size=small episodes=10
    teacher=(--steps 5000 --batch-size 32 --learning-rate 3e-4 --checkpoint-every 500)  # ~2 passes over 75,737 frames
    student=(--steps 2000 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 500)
else
    demos=30 image=64 seen=64 size=small episodes=20
    teacher=(--steps 5000 --batch-size 32 --learning-rate 3e-4 --checkpoint-every 500)
    student=(--steps 2000 --batch-size 32 --learning-rate 3e-5 --warmup-steps 50 --checkpoint-every 500)
fi

cut=(${max_steps:+--max-episode-steps "$max_steps"})  # episodes end there, short of the benchmark's limit
seed="${SEED:-0}"
suffix=$([ "$seed" = 0 ] || echo "-seed$seed")  # seed 0 keeps the folders it always had
teacher+=(--seed "$seed") student+=(--seed "$seed")
data="${DATA:-$out/data}"
[ -f "$out/lerobot/meta/info.json" ] || {
    # demonstrations already in $data are written as the dataset, not collected again; an interrupted collection's
    # finished tasks (in $data/.parts) are kept and the others collected
    snapflow collect --env "$env" --tasks "$tasks" --episodes "$demos" --image-size "$image" --output "$data" \
        --lerobot-dataset "$out/lerobot" "${collect[@]}" "${options[@]}"
}
[ -f "$out/teacher$suffix/lerobot_policy/snapflow.json" ] ||
    snapflow train --policy-type smolvla --smolvlm "$size" --image-size "$seen" --dataset "$out/lerobot" \
        --output "$out/teacher$suffix" --resume ${KEEP:+--keep-progress "$KEEP/teacher$suffix"} "${teacher[@]}" \
        "${options[@]}"
[ -f "$out/student$suffix/lerobot_policy/snapflow.json" ] ||
    snapflow distill --policy "$out/teacher$suffix/lerobot_policy" --dataset "$out/lerobot" --recipe snapflow \
        --output "$out/student$suffix" --resume ${KEEP:+--keep-progress "$KEEP/student$suffix"} "${student[@]}" \
        "${options[@]}"
[ -f "$out/eval$suffix/report.json" ] ||
    snapflow eval --policy "$out/teacher$suffix/lerobot_policy=teacher-10,naive" \
        "$out/student$suffix/lerobot_policy=snapflow-1" --env "$env" --tasks "$tasks" --episodes "$episodes" \
        --data "$data" --output "$out/eval$suffix" --resume "${cut[@]}" "${options[@]}"
if [ "$bench" = libero ]; then
    # the student again, in LeRobot's own LIBERO environment, on the same initial states: one environment per
    # episode (LeRobot's environment k starts from initial state k, and moves on by itself after a success), one
    # task at a time (a LIBERO environment with cameras holds ~850 MB)
    plugins=$(python -c 'from snapflow.adapters.lerobot_types import lerobot_loads_plugins as f; print(int(f()))')
    if [ "$plugins" = 1 ]; then  # LeRobot's lerobot-eval itself, task by task, with the package's initial states
        python - "$out/student$suffix/lerobot_policy" "$tasks" "$episodes" "$image" "$out/lerobot-eval$suffix" \
            "${max_steps:-0}" <<'EOF'
import sys

from snapflow.envs.factory import make_benchmark
from snapflow.evaluation.lerobot_eval import run_lerobot_eval
from snapflow.flow.modes import SNAPFLOW_1

policy, tasks, episodes, image, output, cut = sys.argv[1:]
tasks = make_benchmark("libero").resolve_tasks(tasks)
run_lerobot_eval(policy, tasks, int(episodes), int(image), 4, SNAPFLOW_1, output, max_episode_steps=int(cut) or None)
EOF
    else
        for task in $(python -c "from snapflow.envs.factory import make_benchmark; print(*make_benchmark('libero').resolve_tasks('$tasks'))"); do
            [ -f "$out/lerobot-eval$suffix/$task/report.json" ] ||
                snapflow eval --lerobot-env libero --env-task "$task" --policy "$out/student$suffix/lerobot_policy" \
                    --modes snapflow-1 --episodes "$episodes" --n-envs "$episodes" --n-action-steps 4 \
                    --output "$out/lerobot-eval$suffix/$task" "${cut[@]}" "${options[@]}"
        done
    fi
fi
