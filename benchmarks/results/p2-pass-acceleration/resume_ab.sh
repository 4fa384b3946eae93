#!/bin/bash
# The closed-loop A/Bs of a candidate P2 one pass (CANDIDATE/config.json) against P2's 100 plain iterations, for
# vqvae-filter, vqvae and cvae-filter: own sides from the accelerated pass's records in this folder, changed sides
# resumed from CANDIDATE/<planner>/. Writes OUT/<planner>/verdict.json for each.
#     bash benchmarks/results/p2-pass-acceleration/resume_ab.sh benchmarks/results/p2-pass-acceleration/plain-70 OUT
set -e
base=$(cd "$(dirname "$0")" && pwd)
here=$(cd "${1:?usage: resume_ab.sh CANDIDATE OUT}" && pwd)
out=${2:?usage: resume_ab.sh CANDIDATE OUT}
for pair in vqvae-filter:anderson-50 vqvae:vqvae-anderson-50 cvae-filter:cvae-filter-anderson-50; do
  planner=${pair%%:*}
  own=$base/${pair##*:}
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
