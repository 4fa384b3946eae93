#!/usr/bin/env bash
# The learned priors' shipped weights, from scratch: demonstrations of today's expert on both roads, then the
# CVAE, the VQ-VAE and its PixelCNN per road, then the offline prior metrics on held-out rows. Resumable: every
# step is a driveopt command that resumes (collect appends, the trainers continue from last.ckpt, prior_metrics
# skips the rows it has), so rerunning the same command continues where it stopped.
#
#   nohup bash benchmarks/p2_weights.sh OUT_DIR > OUT_DIR.log 2>&1 &
#
# Both roads run side by side (one process each: the 2-core machine). About 19 min of collection, then
# ~15 min of training and ~2 min of metrics per road (483fbd1: 35 min in all). The weights are not copied into the package: ship
# OUT_DIR/pixelcnn-{four,two}/pixelcnn.ckpt as src/driveopt/weights/vqvae-{four,two}-lane.ckpt and
# OUT_DIR/cvae-{four,two}/cvae.ckpt as cvae-{four,two}-lane.ckpt after reading the histories.
set -euo pipefail
out=${1:?usage: p2_weights.sh OUT_DIR}
repo=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$out"

road() {  # SCENARIO SHORT
    local s=$1 r=$2
    echo "== $s: collect ($(date -u +%H:%M))"
    driveopt collect --scenarios "$s" --episodes 40 --duration 30 --seed 7 --samples 250 --modes 8 \
        --out "$out/$s.h5" $( [ -e "$out/$s.json" ] || echo --json "$out/$s.json" )
    echo "== $s: train cvae ($(date -u +%H:%M))"
    driveopt train cvae --data "$out/$s.h5" --out "$out/cvae-$r"
    echo "== $s: train vqvae ($(date -u +%H:%M))"
    driveopt train vqvae --data "$out/$s.h5" --out "$out/vqvae-$r"
    echo "== $s: train pixelcnn ($(date -u +%H:%M))"
    driveopt train pixelcnn --data "$out/$s.h5" --vqvae "$out/vqvae-$r/vqvae.ckpt" --out "$out/pixelcnn-$r"
    echo "== $s: prior metrics ($(date -u +%H:%M))"
    python "$repo/benchmarks/prior_metrics.py" --data "$out/$s.h5" --validation 0.1 --seed 0 --max-rows 200 \
        --cvae-weights "$out/cvae-$r/cvae.ckpt" --vqvae-weights "$out/pixelcnn-$r/pixelcnn.ckpt" \
        --json "$out/prior_metrics-$r.json"
    echo "== $s: done ($(date -u +%H:%M))"
}

road four-lane-d3.0 four > "$out/four.log" 2>&1 &
road two-lane-d2.5 two > "$out/two.log" 2>&1 &
wait
echo "== both roads done ($(date -u +%H:%M)); logs in $out/four.log and $out/two.log"
