#!/bin/bash
# Time bilevel's projection both ways on this machine: the plain 20 iterations at the nodes against the real-time
# projection (driveopt.registry.REALTIME_PROJECTION, read from the installed package), fixed-work plan() calls
# (latency.py, two rounds, the sides alternating) and 30 s closed-loop drives at 150 and 250 samples. Run it on an idle
# machine, from the repository root:
#   bash benchmarks/perf/realtime_projection_timing.sh OUT
set -euo pipefail
T=${1:?usage: realtime_projection_timing.sh OUT}
mkdir -p "$T"
python - "$T" <<'PY'
import json, sys
from driveopt.registry import REALTIME_PROJECTION
out = sys.argv[1]
others = {k: v for k, v in REALTIME_PROJECTION.items() if k != "max_iterations"}
json.dump({"projection": others}, open(f"{out}/rt-latency.json", "w"))  # latency.py sets the iterations
json.dump({"projection": REALTIME_PROJECTION}, open(f"{out}/rt.json", "w"))
json.dump({"projection": {"max_iterations": 20, "anderson_window": 0, "derivative_bounds": "nodes", "early_iterations": 0}},
          open(f"{out}/plain.json", "w"))
open(f"{out}/rt-iterations", "w").write(str(REALTIME_PROJECTION["max_iterations"]))
PY
RT=$(cat "$T/rt-iterations")
uptime
for round in 1 2; do
  python benchmarks/perf/latency.py --batches 250 1000 --schedules 5x20 --calls 30 --json "$T/latency-plain-$round.json"
  python benchmarks/perf/latency.py --batches 250 1000 --schedules "5x$RT" --calls 30 --config "$T/rt-latency.json" \
      --json "$T/latency-realtime-$round.json"
done
uptime
for side in plain rt; do for n in 150 250; do
  driveopt drive --scenario four-lane-d3.0 --planner bilevel --samples "$n" --duration 30 --seed 42 \
      --config "$T/$side.json" --json "$T/drive-$side-$n.json" --video ''
done; done
uptime
