#!/usr/bin/env bash
# The speed benchmarks on an accelerator, each case's JSON written to OUT as it finishes:
#
#     benchmarks/perf/accelerator.sh OUT [PYTHON]
#
# - call-profile.json: one 1000 x 5 x 20 call split into its parts, the copy of its result to the host timed packed
#   (one buffer per dtype, as plan() copies it there) and per array;
# - latency.json: full plan() calls, 250 and 1000 samples x (5 x 20, 1 x 100), with what each call returned
#   (P1 reports 0.06 s for 1000 x 5 x 20 on its GPU);
# - latency-realtime.json: the same with the real-time projection (driveopt.registry.REALTIME_PROJECTION), 5 x 12
#   as bilevel plans and 5 x 8; latency-realtime-batch4.json: with the batch's nearest 4 neighbours' rows too;
# - vqvae-sampling.json: P2's proposal (PixelCNN, decoder, set-point QP) at 1000 samples;
# - filter-timing.json: P2's pipeline with the plain and the learned filter, 1000 samples x 100 iterations;
# - machine.txt: the accelerator, the driver, Python and JAX.
#
# Runs from a source checkout without installing (PYTHONPATH=src): it needs only jax with the accelerator's
# plugin, numpy, flax, optax, tqdm and h5py, not the simulator. Rerun with the same OUT to resume: finished
# benchmarks and latency cases are kept. Each benchmark has its own time limit (LIMIT seconds, default 300),
# so one that hangs leaves the others their time; CALLS (default 30) timed calls per case.
set -u
out=${1:?usage: benchmarks/perf/accelerator.sh OUT [PYTHON]}
python=${2:-python3}
limit=${LIMIT:-300}
calls=${CALLS:-30}
mkdir -p "$out"
export PYTHONPATH=src${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1

{ nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>&1
  "$python" -c "import jax, platform; print(platform.python_version(), 'jax', jax.__version__, jax.devices())"
  nproc; uptime; } > "$out/machine.txt" 2>&1
cat "$out/machine.txt"

run() {  # NAME ARGS...: one benchmark under the time limit, its log beside its JSON; NAME.done once it succeeded
    local name=$1; shift
    [ -e "$out/$name.done" ] && { echo "== $name: done before"; return; }
    echo "== $name"
    set -o pipefail
    timeout --signal=INT --kill-after=20 "$limit" "$python" "$@" --calls "$calls" 2>&1 | tee -a "$out/$name.log" \
        && touch "$out/$name.done"
}
"$python" - "$out" <<'PY'
import json, sys
from driveopt.registry import REALTIME_PROJECTION
for name, extra in (("realtime", {}), ("realtime-batch4", {"nearest_obstacles": 4, "nearest_choice": "batch"})):
    with open(f"{sys.argv[1]}/config-{name}.json", "w") as f:
        json.dump({"projection": {**REALTIME_PROJECTION, **extra}}, f)
PY
run call-profile benchmarks/perf/call_profile.py --samples 1000 --json "$out/call-profile.json"
run latency-realtime benchmarks/perf/latency.py --batches 1000 250 --schedules 5x12 5x8 --config "$out/config-realtime.json" \
    --resume --json "$out/latency-realtime.json"
run latency benchmarks/perf/latency.py --batches 1000 250 --resume --json "$out/latency.json"
run filter-timing benchmarks/perf/filter_timing.py --iterations 100 --reference 100 --json "$out/filter-timing.json"
run vqvae-sampling benchmarks/perf/vqvae_sampling.py --samples 1000 --resume --json "$out/vqvae-sampling.json"
run latency-realtime-batch4 benchmarks/perf/latency.py --batches 1000 250 --schedules 5x12 \
    --config "$out/config-realtime-batch4.json" --resume --json "$out/latency-realtime-batch4.json"
