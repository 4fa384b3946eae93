#!/usr/bin/env bash
# P2's closed-loop figures (issues 14 and 15) at today's defaults, in priority order, on the shipped weights.
# Resumable: rerun the same command and every point continues where it stopped. Every point's episodes are
# kept in benchmarks/results/p2-3147746 (the planning code of 3147746; f315557's compile-once change keeps the
# closed loops bit for bit, benchmarks/closed_loop_ab.py), so a new machine
# resumes from them; benchmarks/p2_closed_loop.py writes OUT/<figure>.json and .png after every point.
#
#   nohup bash benchmarks/p2_sweeps.sh OUT_DIR [WORKERS] > OUT_DIR.log 2>&1 &
#
# About 25 hours of the 2-core machine in all (1000 samples; 30-50 episodes per point).
# The body is one function, read whole before it runs, so editing this file never changes a sweep in flight.
set -euo pipefail

main() {
    out=${1:?usage: p2_sweeps.sh OUT_DIR [WORKERS]}
    workers=${2:-2}
    repo=$(cd "$(dirname "$0")/.." && pwd)

    sweep() {
        echo "== $*  ($(date -u +%H:%M))"
        python "$repo/benchmarks/p2_closed_loop.py" --out "$out" --workers "$workers" \
            --records "$repo/benchmarks/results/p2-3147746" "$@"
    }

    # Issue 15's target pair: the learned filter at 25 iterations against the plain filter at 100.
    sweep --figure fig8a --planners vqvae vqvae-filter --x 25 100
    # Issue 14: P2 Fig. 7, dense traffic (the references first), then slow traffic.
    sweep --figure fig7 --scenarios p2-four-lane-d3.0 --planners bilevel-p1 idm cvae-filter vqvae-cem
    sweep --figure fig7 --scenarios p2-four-lane-d1.5-slow
    # Issue 15: the rest of Fig. 8a, Fig. 8b and Fig. 9.
    sweep --figure fig8a
    sweep --figure fig8b
    sweep --figure fig9
}

main "$@"
exit
