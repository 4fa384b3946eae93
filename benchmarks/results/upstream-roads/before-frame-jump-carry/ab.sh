#!/bin/bash
# Resumable: the frame-jump carry (wt86d) against the code before it (wt86c), upstream envs, resets 0-19, env by env.
. /work/main/.venv/bin/activate
for env in racetrack-v0 racetrack-oval-v0 racetrack-large-v0 lane-keeping-v0 roundabout-v0 u-turn-v0 intersection-v0 roundabout-generic-v0 "exit-v0"; do
  for side in own:wt86c changed:wt86d; do
    name=${side%%:*}; tree=/work/${side#*:}
    (cd $tree && PYTHONPATH=$tree/src:$tree python benchmarks/studies/upstream_roads.py --out /work/s86/fj/$name --envs "$env" --planners bilevel --episodes 20) || exit 1
  done
done
