#!/usr/bin/env bash
# The full protocols of `driveopt reproduce p1` and `p2`, run a slice at a time in priority order, into the committed
# records under benchmarks/results/reproduction/{p1,p2}; then the reports over everything recorded, copied to
# docs/reproduction/p1-claims.md and p2-claims.md (with their figures).
#
#   nohup bash benchmarks/studies/reproduce_campaign.sh [WORKERS] > LOG 2>&1 &     # run (or resume) the stages, then report
#   bash benchmarks/studies/reproduce_campaign.sh --report                          # only the reports
#
# Resumable: every stage is a `driveopt reproduce` run, which skips the episodes its folders hold, so rerunning this
# script continues where it stopped (SIGTERM or Ctrl-C keep the finished episodes). A stage asks for the first N
# episodes of each seed; later stages ask for more, so the headline comparisons reach two seeds first and every
# row grows over sessions. Both protocols whole are some 600 hours of the 2-core machine (docs/reproduction/README.md:
# P2's 1000-sample pipelines take about 3.5 min per episode with two workers); the stages below state their costs.
# One code version for every session: the episodes run the sources of commit CODE (a git worktree beside the
# checkout), whose digest every record names and each report states; the reports are written by this checkout. When
# the planning code changes its numbers, set CODE to the new commit and remove the records of the planners it changes
# (they run again); records of the others stay, and a report that mixes digests says so. The first records ran
# d621f34 (digest 7fba4df190b7d8b7); 75e44b5 changed `grid` (its records were rerun), 4d346d3 the P1 `*-faithful`
# planners, baa1d47 `vanilla` (theirs were rerun); the other planners plan the same in all of them (0e4321d shares an
# arm's bench folder among the figures that compare it: `driveopt reproduce` merged the earlier per-figure folders);
# be3fcc9 ships the four-lane learned filter retrained on the shipped VQ-VAE's samples (the `vqvae-filter` and
# `vqvae-filter-faithful` records were removed and run again); 5124923 ships P2's baseline [5] (`cvae-multipliers`);
# 3b2f12a records each episode's processor model (plan times are compared within one model).
# The body is one function, read whole before it runs, so editing this file never changes a campaign in flight.
set -euo pipefail

CODE=3b2f12a

main() {
    repo=$(cd "$(dirname "$0")/../.." && pwd)
    records="$repo/benchmarks/results/reproduction"
    code_tree="$repo/../driveopt-campaign-$CODE"
    [ -d "$code_tree/src/driveopt" ] || git -C "$repo" worktree add --detach "$code_tree" "$CODE"
    workers=2
    report_only=0
    case "${1:-}" in
        --report) report_only=1 ;;
        "") ;;
        *) workers=$1 ;;
    esac

    stage() {  # PAPER EPISODES FIGURE [driveopt reproduce options]
        local paper=$1 episodes=$2 figure=$3
        shift 3
        echo "== $paper $figure, $episodes episodes per seed: $*  ($(date -u +%H:%M))"
        PYTHONPATH="$code_tree/src" python -m driveopt.cli reproduce "$paper" --figures "$figure" --episodes "$episodes" \
            --workers "$workers" --out "$records/$paper" "$@"
    }

    report() {  # PAPER: the report of the full protocol over every recorded episode (by this checkout's code, whose
                # protocols name the claims), and its copy in docs/
        local paper=$1
        [ -d "$records/$paper/runs" ] || return 0
        python -m driveopt.cli reproduce "$paper" --report-only --out "$records/$paper"
        sed -E "s#\]\((fig[0-9a-z]+\.png)\)#](${paper}-\1)#" "$records/$paper/report.md" > "$repo/docs/reproduction/$paper-claims.md"
        for png in "$records/$paper"/fig*.png; do
            cp "$png" "$repo/docs/reproduction/$paper-$(basename "$png")"
        done
    }

    if [ "$report_only" = 0 ]; then
        local p1_dense="four-lane-d3.0 two-lane-d2.5" p1_driveopt="bilevel random grid batch vanilla"
        # First, the learned filter against the plain one on at least 150 pairs (the pooled question of the P2 report): P2
        # Fig. 8b's 250-sample point, 75 episodes per seed (at 250 samples an episode costs about a quarter of one at
        # 1000, about 46 s with two workers).
        stage p2 75 fig8b --planners vqvae-filter vqvae --arm-samples 250
        # Then one episode per seed of every P2 figure, so that every claim has a measured row: the retrained learned
        # filter's and P2's baseline [5]'s arms have none yet (39 arms, 78 episodes; a 1000-sample episode takes a
        # worker 4-7 min and two run at once: about 4 h).
        for figure in fig7 fig9 fig8a fig8b; do stage p2 1 $figure; done
        # The headline comparisons at 5 episodes per seed: P1 Fig. 7's dense roads, driveopt's rows (about 7 min per
        # episode index of both seeds and roads), and P2 Fig. 7's density 3, driveopt's pipelines (about 3.5 min per
        # episode).
        stage p1 5 fig7 --scenarios $p1_dense --planners $p1_driveopt
        stage p2 5 fig7 --scenarios p2-four-lane-d3.0 --planners vqvae-filter vqvae cvae-multipliers cvae-filter
        # One episode per seed of every P1 figure: P1's cheaper arms first, then the authors' MPC baselines at their
        # 1000 samples x 100 iterations.
        stage p1 1 fig7 --planners $p1_driveopt cvae-faithful
        for figure in fig8 fig12 fig9 fig10; do stage p1 1 $figure; done
        stage p1 1 fig7
        for episodes in 5 10; do
            # P2 Fig. 7, density 3: driveopt's pipelines, then the faithful ones.
            stage p2 $episodes fig7 --scenarios p2-four-lane-d3.0 --planners vqvae-filter vqvae cvae-multipliers cvae-filter
            stage p2 $episodes fig7 --scenarios p2-four-lane-d3.0 --planners vqvae-filter-faithful \
                cvae-multipliers-faithful cvae-filter-faithful
            # P1 Fig. 7, dense roads, driveopt's rows and the faithful MPC-Bi-Level.
            stage p1 $episodes fig7 --scenarios $p1_dense --planners $p1_driveopt cvae-faithful
        done
        # The authors' MPC baselines at their 1000 samples x 100 iterations: 5-7 min per episode, about 4 h for 2
        # episodes per seed on both dense roads.
        stage p1 2 fig7 --scenarios $p1_dense
        for episodes in 25 50; do
            stage p1 $episodes fig7 --scenarios $p1_dense --planners $p1_driveopt cvae-faithful
            stage p2 $episodes fig7 --scenarios p2-four-lane-d3.0
        done
        # Then every other figure at its full protocol.
        stage p1 50 fig7
        stage p2 50 fig7
        for figure in fig8 fig9 fig10 fig12; do stage p1 50 $figure; done
        for figure in fig8a fig8b fig9; do stage p2 50 $figure; done
    fi
    report p1
    report p2
    # the numbers docs/reproduction/README.md quotes, from the reports just written
    PYTHONPATH="$repo/src" python -m driveopt.experiments.reproduce_prose "$repo/docs/reproduction/README.md" "$records"
}

main "$@"
exit
