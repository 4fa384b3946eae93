#!/usr/bin/env bash
# The closed-loop tables of the README's issue-13 sections, one bench folder each, in priority order.
# Resumable: rerun the same command and every folder continues where it stopped (bench never repeats
# or loses an episode). Each finished folder's records are copied to benchmarks/results/NAME (small
# JSON lines and the summaries), so the README's numbers are kept with the code that produced them;
# a folder missing from OUT starts from the records kept there (a new machine resumes them).
#
#   nohup bash benchmarks/studies/readme_tables.sh OUT_DIR [WORKERS] > OUT_DIR.log 2>&1 &
#
# Every table: seed 42, 50 episodes of 50 s, 250 samples per sampler iteration.
set -euo pipefail
out=${1:?usage: readme_tables.sh OUT_DIR [WORKERS]}
workers=${2:-2}
repo=$(cd "$(dirname "$0")/../.." && pwd)
results="$repo/benchmarks/results"

table() {  # NAME SCENARIOS -- PLANNERS
    local name=$1; shift
    local scenarios=()
    while [ "$1" != "--" ]; do scenarios+=("$1"); shift; done
    shift
    echo "== $name: ${scenarios[*]} x $*  ($(date -u +%H:%M))"
    if [ ! -e "$out/$name/episodes.jsonl" ] && [ -e "$results/$name/episodes.jsonl" ]; then
        mkdir -p "$out/$name"
        cp "$results/$name/episodes.jsonl" "$results/$name/spec.json" "$out/$name/"
    fi
    driveopt bench --scenarios "${scenarios[@]}" --planners "$@" --seeds 42 --episodes 50 --samples 250 \
        --workers "$workers" --out "$out/$name"
    mkdir -p "$results/$name"
    cp "$out/$name/episodes.jsonl" "$out/$name/spec.json" "$out/$name/summary.md" "$results/$name/"
}

# P1's claim (bilevel >= 4x fewer collisions than its MPC baselines) on both dense roads.
table p1-dense four-lane-d3.0 two-lane-d2.5 -- random-p1 grid-p1 batch-p1 vanilla-p1
# P1 Fig. 8: the shipped DQN and PPO policies (bilevel and idm on two-lane-d1.0: sparse-two; on four-lane-d3.0: dense-four).
table rl-two two-lane-d1.0 -- dqn ppo
table rl-four four-lane-d3.0 -- dqn ppo
# P1 Fig. 7's low-density settings.
table sparse-two two-lane-d1.0 -- bilevel idm random-p1 grid-p1 batch-p1 vanilla-p1
table sparse-four four-lane-d1.5 -- bilevel idm random-p1 grid-p1 batch-p1 vanilla-p1
# The default planner with today's defaults (the course bound) on the four roads above; compared with idm in
# the dense-* and sparse-* folders (`driveopt summarise A B --reference idm`). About 20 min each on 2 cores.
table bilevel-dense-four four-lane-d3.0 -- bilevel
table bilevel-dense-two two-lane-d2.5 -- bilevel
table bilevel-sparse-four four-lane-d1.5 -- bilevel
table bilevel-sparse-two two-lane-d1.0 -- bilevel
# Every optimiser on the dense roads, with idm in the same folder for the per-episode comparison; the
# single-pass optimisers (minutes per table) apart from the bi-level ones (about an hour each on 2 cores).
# The sparse-* folders' and the *-bilevel folders' bilevel rows predate the course bound (see the README).
table dense-four four-lane-d3.0 -- idm random grid batch vanilla
table dense-two two-lane-d2.5 -- idm random grid batch vanilla
table cvae-dense-four four-lane-d3.0 -- cvae cvae-mix
table dense-four-bilevel four-lane-d3.0 -- bilevel bilevel-p1 cvae cvae-mix
table dense-two-bilevel two-lane-d2.5 -- bilevel bilevel-p1 cvae cvae-mix
echo "== all tables done ($(date -u +%H:%M))"
