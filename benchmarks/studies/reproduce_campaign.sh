#!/usr/bin/env bash
# The reproduction campaign: decisions on the papers' claims bought cheapest first, into the committed records under
# benchmarks/results/reproduction/{p1,p2}; then the reports over everything recorded, copied to
# docs/reproduction/p1-claims.md and p2-claims.md (with their figures).
#
#   nohup bash benchmarks/studies/reproduce_campaign.sh [WORKERS] > LOG 2>&1 &     # run (or resume) the steps, then report
#   bash benchmarks/studies/reproduce_campaign.sh --report                          # only the reports
#   HOURS=1 bash benchmarks/studies/reproduce_campaign.sh 2                         # each step's budget (default 2 h)
#
# Each step is `driveopt reproduce PAPER --decide HOURS` on a slice of the claims: it runs the cheapest undecided claim
# of `--plan` up to its next sequential look, plans again, and so on, so every claim stops at the look where its
# O'Brien-Fleming boundary decides it. Resumable: the bench runs skip the episodes their folders hold, so rerunning
# this script continues where it stopped (SIGTERM or Ctrl-C keep the finished episodes).
# The steps, in order: P2 Fig. 7's headline (density 3) with P2's pipeline and [5]'s as their authors ran them, and
# P2 Fig. 9's faithful rows (the no-filter arms cost seconds an episode); P1 Fig. 7's dense roads with the faithful
# MPC-Bi-Level (`cvae-faithful`) against the authors' MPC-Random, MPC-Grid, MPC-Vanilla and Batch-MPC (their faithful
# arms crash within seconds, so a pair is cheap), and driveopt's rows of the same figure; P2 Fig. 9's rows and P2
# Fig. 7's density 3, driveopt's pipelines.
# One code version for every session: the episodes run the sources of commit CODE (a git worktree beside the
# checkout), whose digest every record names and each report states; the reports are written by this checkout. When
# the planning code changes its numbers, set CODE to the new commit and remove the records of the planners it changes
# (they run again); records of the others stay, and a report that mixes digests says so. Records before a22a706's ran
# 3b2f12a and earlier (the reports name each digest); a22a706 plans every registered planner bit for bit as 3992e16
# (benchmarks/results/closed-loop-ab/every-planner/), whose rounding differs from 3b2f12a's. defe7ca changed
# `batch-faithful` (its authors' Batch-MPC expert) and P2's faithful pipelines (their authors' command, start and
# ranking), whose earlier records were removed; the other planners it plans as a22a706 (`driveopt closed-loop-ab` on
# cvae-faithful, cvae-multipliers-faithful, bilevel, vqvae-filter and grid: identical step by step). 40ddb4f plans every
# planner as defe7ca (`driveopt closed-loop-ab` on those five, vqvae-filter-faithful and batch-faithful: identical,
# benchmarks/results/closed-loop-ab/campaign-code/) and decides claims as the reports do (a direction the protocol cannot
# show at the measured rates is not decidable; no claim is run past its last look).
# b45dbdc plans every planner as 40ddb4f (the same seven: identical; its changes are to crossing traffic, junction frames
# and curve speed, which the papers' straight roads never reach).
# The body is one function, read whole before it runs, so editing this file never changes a campaign in flight.
set -euo pipefail

CODE=b45dbdc
# Its protocols name vqvae-filter's P2 arms without the filter pass P2's comparisons share, which today's name (its own
# default became faster): its episodes of those arms would go to folders the reports no longer read. Today's code
# plans P2's pipelines otherwise than CODE (benchmarks/results/closed-loop-ab/p2-at-b45dbdc/), so moving CODE for P2
# means running P2's records again (docs/reproduction/README.md).

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

    decide() {  # PAPER [driveopt reproduce options]: the cheapest decisions among those claims, for HOURS
        local paper=$1
        shift
        echo "== $paper: deciding for ${HOURS:-2} h: $*  ($(date -u +%H:%M))"
        PYTHONPATH="$code_tree/src" python -m driveopt.cli reproduce "$paper" --decide "${HOURS:-2}" \
            --workers "$workers" --out "$records/$paper" "$@"
    }

    claim() {  # PAPER ID EPISODES: one claim's two arms, to EPISODES per seed (past the looks --decide would stop at:
               # P2's headline straight to its second look)
        echo "== $1: $2 to $3 episodes per seed  ($(date -u +%H:%M))"
        PYTHONPATH="$code_tree/src" python -m driveopt.cli reproduce "$1" --claim "$2" --episodes "$3" \
            --workers "$workers" --out "$records/$1"
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
        local p1_dense="four-lane-d3.0 two-lane-d2.5"
        # P2's headline and Fig. 9, the pipelines as their authors ran them.
        claim p2 fig7:p2-four-lane-d3.0:vqvae-filter-faithful-vs-cvae-multipliers-faithful:collisions 10
        # P2 Fig. 9 at density 3, with the filter against without it: each row to the look that decides it (driveopt's
        # rows to their second look, where rates of 0 against 0 are not decidable; the faithful row to its third).
        claim p2 fig9:p2-four-lane-d3.0:vqvae-filter-faithful@n1000-vs-vqvae-filter-faithful@n1000-maxiterations0:collisions 20
        claim p2 fig9:p2-four-lane-d3.0:cvae-filter@n1000-vs-cvae-filter@n1000-maxiterations0:collisions 10
        # P1 Fig. 7's dense roads: the faithful MPC-Bi-Level against the authors' MPC baselines (the rows short of
        # their first look first), then driveopt's rows.
        claim p1 fig7:four-lane-d3.0:cvae-faithful-vs-grid-faithful:collisions 5
        claim p1 fig7:four-lane-d3.0:cvae-faithful-vs-batch-faithful:collisions 5
        claim p1 fig7:two-lane-d2.5:cvae-faithful-vs-batch-faithful:collisions 5
        decide p1 --figures fig7 --scenarios $p1_dense --planners cvae-faithful random-faithful grid-faithful vanilla-faithful batch-faithful
        # P2 Fig. 9's faithful rows: without the filter at density 3 and the primary claim to their first looks,
        # then the cheapest decisions.
        claim p2 fig9:p2-four-lane-d3.0:vqvae-filter-faithful@n1000-vs-vqvae-filter-faithful@n1000-maxiterations0:collisions 5
        claim p2 fig9:p2-four-lane-d3.0:cvae-filter-faithful@n1000-vs-cvae-filter-faithful@n1000-maxiterations0:collisions 5
        claim p2 fig9:p2-four-lane-d1.5:vqvae-filter-faithful-vs-cvae-multipliers-faithful:collisions 5
        decide p2 --figures fig9 --planners vqvae-filter-faithful cvae-multipliers-faithful cvae-filter-faithful
        decide p1 --figures fig7 --scenarios $p1_dense --planners bilevel random grid batch vanilla
        # P2 Fig. 9 (with and without the filter) and Fig. 7 at density 3, driveopt's pipelines; vqvae-filter's arms wait
        # for CODE to move (above).
        decide p2 --figures fig9 --planners cvae-multipliers cvae-filter
        decide p2 --figures fig7 --scenarios p2-four-lane-d3.0 --planners vqvae cvae-multipliers cvae-filter
    fi
    report p1
    report p2
    # the numbers docs/reproduction/README.md quotes, from the reports just written
    PYTHONPATH="$repo/src" python -m driveopt.experiments.reproduce_prose "$repo/docs/reproduction/README.md" "$records"
}

main "$@"
exit
