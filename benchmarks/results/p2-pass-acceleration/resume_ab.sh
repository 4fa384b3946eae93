#!/bin/bash
# The closed-loop A/Bs of a candidate P2 one pass (CANDIDATE/config.json) against P2's 100 plain iterations, for
# vqvae-filter, vqvae and cvae-filter. The P1 roads' episodes repeat across machines, so their own sides come from the
# accelerated pass's records in this folder and their changed sides resume from CANDIDATE/<planner>/changed (setting_ab.py
# drives each copied side's first episode again and refuses it unless it repeats here); the highway-v0 episodes do
# not, so both of its sides are driven on this machine. Writes OUT/<planner>/verdict.json.
#     bash benchmarks/results/p2-pass-acceleration/resume_ab.sh benchmarks/results/p2-pass-acceleration/anderson-60-control-points OUT
set -e
base=$(cd "$(dirname "$0")" && pwd)
here=$(cd "${1:?usage: resume_ab.sh CANDIDATE OUT}" && pwd)
out=${2:?usage: resume_ab.sh CANDIDATE OUT}
for pair in vqvae-filter:anderson-50 vqvae:vqvae-anderson-50 cvae-filter:cvae-filter-anderson-50; do
  planner=${pair%%:*}
  mkdir -p "$out/$planner"
  [ -d "$out/$planner/own" ] || cp -r "$base/${pair##*:}/own" "$out/$planner/"
  if [ -d "$here/$planner/changed" ] && [ ! -d "$out/$planner/changed" ]; then cp -r "$here/$planner/changed" "$out/$planner/"; fi
  python benchmarks/studies/setting_ab.py --config "$here/config.json" --planner "$planner" --out "$out/$planner" \
    --scenarios four-lane-d3.0 two-lane-d2.5 --upstream highway-v0
done
