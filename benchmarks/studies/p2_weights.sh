#!/usr/bin/env bash
# The learned priors' shipped weights, from scratch: demonstrations of today's expert on both roads (the four-lane
# road also in P2's traffic, dense and slow, where neighbours may stand for good), then the CVAE, the VQ-VAE and its
# PixelCNN per road, then the offline prior metrics on held-out rows. Resumable: every
# step is a driveopt command that resumes (collect appends, the trainers continue from last.ckpt, prior_metrics
# skips the rows it has), so rerunning the same command continues where it stopped.
#
#   nohup bash benchmarks/studies/p2_weights.sh OUT_DIR > OUT_DIR.log 2>&1 &
#
# Both roads run side by side (one process each: the 2-core machine). About 25 min of collection, then
# ~10 min of training and ~3 min of metrics per road. The weights are not copied into the package: ship
# OUT_DIR/pixelcnn-{four,two}/pixelcnn.ckpt as src/driveopt/weights/vqvae-{four,two}-lane.ckpt and
# OUT_DIR/cvae-{four,two}/cvae.ckpt as cvae-{four,two}-lane.ckpt after reading the histories.
set -euo pipefail
out=${1:?usage: p2_weights.sh OUT_DIR}
repo=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$out"

collect() {  # SCENARIO EPISODES
    local s=$1 n=$2
    echo "== $s: collect ($(date -u +%H:%M))"
    driveopt collect --scenarios "$s" --episodes "$n" --duration 30 --seed 7 --samples 250 --modes 8 \
        --out "$out/$s.h5" $( [ -e "$out/$s.json" ] || echo --json "$out/$s.json" )
}

road() {  # SHORT PIXELCNN_EPOCHS SCENARIO:EPISODES ...  (every scenario on the same road: one lane count)
    local r=$1 epochs=$2 data=() spec
    shift 2
    for spec in "$@"; do
        collect "${spec%%:*}" "${spec##*:}"
        data+=("$out/${spec%%:*}.h5")
    done
    echo "== $r: train cvae ($(date -u +%H:%M))"
    driveopt train cvae --data "${data[@]}" --out "$out/cvae-$r"
    echo "== $r: train vqvae ($(date -u +%H:%M))"
    driveopt train vqvae --data "${data[@]}" --out "$out/vqvae-$r"
    echo "== $r: train pixelcnn ($(date -u +%H:%M))"
    driveopt train pixelcnn --data "${data[@]}" --vqvae "$out/vqvae-$r/vqvae.ckpt" --out "$out/pixelcnn-$r" --epochs "$epochs"
    echo "== $r: prior metrics ($(date -u +%H:%M))"
    python -m driveopt.experiments.prior_metrics --data "${data[@]}" --validation 0.1 --seed 0 --max-rows 200 \
        --cvae-weights "$out/cvae-$r/cvae.ckpt" --vqvae-weights "$out/pixelcnn-$r/pixelcnn.ckpt" \
        --json "$out/prior_metrics-$r.json"
    echo "== $r: done ($(date -u +%H:%M))"
}

# PixelCNN: the best held-out epoch is kept, and it comes within the first 10 (it overfits after a few).
road four 20 four-lane-d3.0:40 p2-four-lane-d3.0:20 p2-four-lane-d1.5-slow:20 > "$out/four.log" 2>&1 &
road two 60 two-lane-d2.5:40 > "$out/two.log" 2>&1 &
wait
echo "== both roads done ($(date -u +%H:%M)); logs in $out/four.log and $out/two.log"
