#!/bin/bash
# The closed-loop A/Bs of P2's one pass at 80 plain iterations with the speed and acceleration bounds at control points
# (config.json) against P2's 100 plain iterations, for vqvae-filter, vqvae and cvae-filter: own sides from the records
# beside this folder, changed sides resumed from the records in it. Writes OUT/<planner>/verdict.json for each.
#     bash benchmarks/results/p2-pass-acceleration/plain-80-control-points/resume.sh OUT
set -e
here=$(cd "$(dirname "$0")" && pwd)
out=${1:?usage: resume.sh OUT}
for pair in vqvae-filter:anderson-50 vqvae:vqvae-anderson-50 cvae-filter:cvae-filter-anderson-50; do
  planner=${pair%%:*}
  own=$here/../${pair##*:}
  mkdir -p "$out/$planner"
  for side in own upstream-own; do
    [ -d "$out/$planner/$side" ] || cp -r "$own/$side" "$out/$planner/"
  done
  for side in changed upstream-changed; do
    if [ -d "$here/$planner/$side" ] && [ ! -d "$out/$planner/$side" ]; then cp -r "$here/$planner/$side" "$out/$planner/"; fi
  done
  python benchmarks/studies/setting_ab.py --config "$here/config.json" --planner "$planner" --out "$out/$planner" \
    --scenarios four-lane-d3.0 two-lane-d2.5 --upstream highway-v0
done
