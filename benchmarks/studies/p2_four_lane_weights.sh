#!/usr/bin/env bash
# The four-lane weights that learn from the shipped VQ-VAE's setting: P2's learned safety filter, retrained on samples
# of the shipped four-lane VQ-VAE (`weights/vqvae-four-lane.ckpt`, trained in P2's traffic), and P2's baseline [5]
# (`cvae-multipliers`). Both learn from the demonstrations the shipped VQ-VAE learned from (benchmarks/studies/p2_weights.sh:
# today's expert on four-lane-d3.0 and on P2's dense and slow traffic, 30 s episodes, seed 7).
#
#   nohup bash benchmarks/studies/p2_four_lane_weights.sh OUT_DIR > OUT_DIR.log 2>&1 &
#
# Steps, each resumable (collect appends to its files, the trainers continue from last.ckpt, which the filter's
# trainer also saves inside an epoch), so rerunning the same command continues where it stopped:
#   1. collect 40 + 20 + 20 episodes, two at a time (about 25 min on the 2-core machine);
#   2. `driveopt train filter` with its defaults (P2's eq. 9, samples of the shipped VQ-VAE) and --validation 0.1,
#      2 epochs (39 min each on its 20 755 observations here);
#   3. the filter's offline residuals against the plain filter on 500 held-out rows (benchmarks/studies/filter_residuals.py);
#   4. `driveopt train cvae-multipliers` through the planner's set-point QP and 20 unrolled projection iterations
#      (60 epochs, 24 min here).
# One process at a time (the 2-core machine). Nothing is copied into the package: ship OUT_DIR/filter-four/filter.ckpt
# as src/driveopt/weights/filter-four-lane.ckpt and OUT_DIR/cvae-multipliers-four/cvae-multipliers.ckpt as
# src/driveopt/weights/cvae-multipliers-four-lane.ckpt after reading the histories and the residuals.
set -euo pipefail

main() {
    out=${1:?usage: p2_four_lane_weights.sh OUT_DIR}
    repo=$(cd "$(dirname "$0")/../.." && pwd)
    mkdir -p "$out"
    data=()
    for spec in four-lane-d3.0:40 p2-four-lane-d3.0:20 p2-four-lane-d1.5-slow:20; do
        local s=${spec%%:*} n=${spec##*:}
        echo "== $s: collect $n episodes ($(date -u +%H:%M))"
        driveopt collect --scenarios "$s" --episodes "$n" --duration 30 --seed 7 --samples 250 --modes 8 --workers 2 \
            --out "$out/$s.h5" $( [ -e "$out/$s.json" ] || echo --json "$out/$s.json" )
        data+=("$out/$s.h5")
    done
    echo "== train filter ($(date -u +%H:%M))"
    driveopt train filter --data "${data[@]}" --out "$out/filter-four" --validation 0.1 --epochs 2
    echo "== filter residuals ($(date -u +%H:%M))"
    [ -e "$out/filter-residuals.json" ] || python "$repo/benchmarks/studies/filter_residuals.py" --data "${data[@]}" \
        --filter-weights "$out/filter-four/filter.ckpt" --validation 0.1 --seed 0 --max-rows 500 \
        --json "$out/filter-residuals.json"
    echo "== train cvae-multipliers ($(date -u +%H:%M))"
    driveopt train cvae-multipliers --data "${data[@]}" --out "$out/cvae-multipliers-four" --validation 0.1
    echo "== done ($(date -u +%H:%M))"
}

main "$@"
exit
