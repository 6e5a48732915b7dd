#!/usr/bin/env bash
# Batch-1 latency on a GPU of the LeRobot architectures at full size (random weights: timing does not depend on the
# values) on the recommended fast path, `deploy`: pi0.5 first from a cold start (an empty compile cache; a short
# timing), then from a warm one (the cache the first run filled: a new process's start) with the full timing and
# the profile; then SmolVLA (its VLM's config written locally at SmolVLM2-500M's size) and pi0, each from a cold start
# (docs/results/latency-gpu-*/).
#
#   bash scripts/gpu_latency.sh [OUTPUT] [ARCHITECTURE ...]   # default outputs/latency-gpu; pi05 smolvla pi0
#   SHORT=1 bash scripts/gpu_latency.sh OUTPUT                 # the chain on the CPU: the MLP, two repeats
#   LIMIT=SECONDS ...                                          # the most one bench may take (default 400)
#   PROMPT=N ...                                               # N real prompt tokens, the rest padding (default:
#                                                              # all real; deploy cuts the padding)
#
# Each bench writes OUTPUT/<architecture>-<device>[-cold]/ and its log beside it; a finished one is kept when the
# script runs again. The compile cache is OUTPUT/compile-cache.
#
# On a lent GPU machine (Python 3.12, torch, transformers and the rest already there, nothing to download), carry
# what it lacks as wheels fetched here into a git-excluded .whl/ (55 MB), snapflow's own among them (run from src/
# alone it has no version to read), and install them there:
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
#       lerobot==0.6.1 draccus==0.11.6 mergedeep==1.3.4 toml==0.10.2 gymnasium==1.4.0 farama-notifications \
#       datasets==4.8.5 dill==0.4.1 multiprocess==0.70.19 termcolor==3.3.0 transformers==5.5.4 tokenizers==0.22.2 \
#       av==15.1.0 num2words==0.5.14
#   python -m pip wheel --no-deps --no-build-isolation -w .whl .
#   (there) python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl
#           PYTHONPATH=/tmp/site bash scripts/gpu_latency.sh /tmp/lat pi05
# On an H200 (2026-11-28) pi0.5's cold bench took 196 s (model built on the GPU, then the one-step graph and the
# teacher's graphs compiled) and the warm one 69 s; SmolVLA at full size ran past 135 s cold and pi0 past 125 s:
# give LIMIT 330 or more, pi0.5's two runs one 10-minute call, SmolVLA and pi0 another. Which part of deploy moves the actions how far:
# python3 scripts/deploy_parity.py --architecture pi05 --dtype bfloat16 --output /tmp/parity.
set -uo pipefail
out="${1:-outputs/latency-gpu}"
shift $(($# > 0 ? 1 : 0))
architectures=("${@:-pi05}")
[ $# -gt 0 ] || architectures=(pi05 smolvla pi0)
timing=()
if [ "${SHORT:-0}" = 1 ]; then
    architectures=(mlp) timing=(--warmup 1 --repeats 2 --no-profile)
fi
device=$(python3 -c 'import torch; print(torch.cuda.get_device_name().split()[1].lower() if torch.cuda.is_available() else "cpu")')
mkdir -p "$out"
if [ "$device" != cpu ]; then  # the CUDA graph a deploy chunk replays, checked on this GPU before anything is timed
    python3 -m pytest -q -p no:cacheprovider tests/inference/test_cuda_graph.py >"$out/cuda-graph-tests.log" 2>&1 ||
        { tail -n 30 "$out/cuda-graph-tests.log"; exit 1; }
fi

bench() {  # FOLDER, then snapflow bench's arguments
    local folder="$out/$1"
    shift
    [ -f "$folder/bench.json" ] && return 0
    local began=$SECONDS
    timeout "${LIMIT:-400}" python3 -m snapflow.cli bench "$@" --fast-path deploy --compile-cache "$out/compile-cache" \
        ${PROMPT:+--prompt-tokens "$PROMPT"} --batch-sizes 1 --no-progress --output "$folder" >"$folder.log" 2>&1
    local status=$?  # 124: stopped at LIMIT
    echo "${folder##*/}: exit $status after $((SECONDS - began)) s"
}

for architecture in "${architectures[@]}"; do
    case "$architecture" in
        pi05 | pi0) options=(--architecture "$architecture" --dtype bfloat16) ;;
        smolvla) options=(--architecture smolvla --smolvlm full) ;;
        *) options=(--architecture "$architecture") ;;
    esac
    if [ "$architecture" = "${architectures[0]}" ]; then  # the cold start, then the warm one
        bench "$architecture-$device-cold" "${options[@]}" --warmup 2 --repeats 5 --no-profile
    fi
    bench "$architecture-$device" "${options[@]}" "${timing[@]}"
done
