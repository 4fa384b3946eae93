#!/usr/bin/env bash
# Weights for P2's baseline [5] (`cvae-multipliers`): the four-lane demonstrations of the shipped CVAE's training
# (docs/results/learned-prior.md: today's expert on four-lane-d3.0 and on P2's dense and slow traffic), then
# `driveopt train cvae-multipliers` through the planner's set-point QP and 20 unrolled projection iterations ([5]'s).
# Resumable: collect appends to its files and the trainer continues from last.ckpt, so rerunning the same command
# continues where it stopped.
#
#   nohup bash benchmarks/cvae_multipliers_weights.sh OUT_DIR > OUT_DIR.log 2>&1 &
#
# One process at a time (the 2-core machine): about 35 min of collection, then the training. The weights are not
# copied into the package: the planners take OUT_DIR/cvae-multipliers-four/cvae-multipliers.ckpt as --weights (no
# file ships for them yet; shipping one means a lookup like the other learned planners' and the protocols' switch from
# the cvae-filter stand-in).
set -euo pipefail

main() {
    out=${1:?usage: cvae_multipliers_weights.sh OUT_DIR}
    mkdir -p "$out"
    data=()
    for spec in four-lane-d3.0:40 p2-four-lane-d3.0:20 p2-four-lane-d1.5-slow:20; do
        local s=${spec%%:*} n=${spec##*:}
        echo "== $s: collect $n episodes ($(date -u +%H:%M))"
        driveopt collect --scenarios "$s" --episodes "$n" --duration 30 --seed 7 --samples 250 --modes 8 \
            --out "$out/$s.h5" $( [ -e "$out/$s.json" ] || echo --json "$out/$s.json" )
        data+=("$out/$s.h5")
    done
    echo "== train cvae-multipliers ($(date -u +%H:%M))"
    driveopt train cvae-multipliers --data "${data[@]}" --out "$out/cvae-multipliers-four" --validation 0.1
    echo "== done ($(date -u +%H:%M))"
}

main "$@"
exit
