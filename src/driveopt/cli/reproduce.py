"""``driveopt reproduce p1|p2``: every declared figure protocol of a paper through the bench store, then a report.

Figures, seeds, planners, scenarios and weights are checked before the output folder is touched; a folder another
reproduction is writing is refused at once. ``--plan`` reads the records alone and prints, for each undecided claim,
its id, the pairs a decision needs and their cost; ``--claim ID`` runs that claim's two arms, only the missing pairs. Ctrl-C stops at once with ``driveopt: interrupted: ...`` and status 130;
the finished episodes are kept and the same command resumes.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import positive_float, positive_int, seed


def register(sub) -> None:
    p = sub.add_parser("reproduce", help="run the declared protocols of a paper's figures; report with intervals, "
                                         "paired tests and verdicts")
    p.add_argument("paper", choices=["p1", "p2"], help="P1 (bi-level + CVAE) or P2 (VQ-VAE + safety filter)")
    p.add_argument("--figures", nargs="+", metavar="FIG", help="only these figures, e.g. fig7 fig9 (default: all)")
    p.add_argument("--quick", action="store_true",
                   help="the quick variants: seed 42, 2 episodes of 4 s, a tenth of the samples (minutes, not hours)")
    p.add_argument("--seeds", nargs="+", type=seed, help="traffic seeds of every figure (default: 42 123)")
    p.add_argument("--episodes", type=positive_int, help="episodes per scenario, planner and seed (default: 50)")
    p.add_argument("--scenarios", nargs="+", metavar="S",
                   help="run only these scenarios' episodes (the report still has every claim of the figures)")
    p.add_argument("--planners", nargs="+", metavar="P",
                   help="run only these planners' episodes (the report still has every claim of the figures)")
    p.add_argument("--arm-samples", nargs="+", type=positive_int, metavar="N",
                   help="run only the arms planning with these samples per sampler iteration, e.g. 250 of P2 Fig. 8b "
                        "(the report still has every claim of the figures)")
    p.add_argument("--report-only", action="store_true",
                   help="run nothing: write the report of the episodes recorded under --out")
    p.add_argument("--plan", action="store_true",
                   help="run nothing, write nothing: print each undecided claim's id, the pairs a decision needs at the "
                        "paper's size and at the measured rates, and their cost from the recorded episode times")
    p.add_argument("--claim", metavar="ID",
                   help="run only this claim's two arms, only its missing pairs (ids as --plan prints them, e.g. "
                        "fig7:four-lane-d3.0:cvae-faithful-vs-random-faithful:collisions); the report covers every claim")
    p.add_argument("--decide", type=positive_float, metavar="HOURS",
                   help="buy decisions at least cost for HOURS: run the cheapest undecided claim up to its next look, "
                        "plan again, and so on (--figures, --scenarios, --planners and --arm-samples narrow the claims "
                        "to those whose arms they hold); ends with the full report")
    p.add_argument("--workers", type=positive_int, help="parallel episodes (default: the CPUs it may use)")
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="local processes, or Ray (RAY_ADDRESS names the cluster; needs driveopt[ray])")
    p.add_argument("--out", required=True, help="output folder (rerun to resume): runs/, report.md, report.json, PNGs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from driveopt.experiments.reproduce import ReproduceError, RunSlice, decide, plan, plan_text, reproduce
    from driveopt.experiments.reproduce_report import distinct_tests, verdict_counts

    seeds = tuple(args.seeds) if args.seeds else None
    if args.plan:
        if args.claim or args.report_only or args.quick or args.decide:
            raise ReproduceError("--plan runs nothing: give it without --claim, --decide, --report-only or --quick")
        rows, claims = plan(args.paper, args.out, figures=args.figures, seeds=seeds, episodes=args.episodes)
        print(plan_text(args.paper, rows, claims), end="")
        return 0
    only = RunSlice(_names(args.scenarios), _names(args.planners), _names(args.arm_samples))
    if args.decide:
        if args.claim or args.report_only or args.quick or args.seeds or args.episodes:
            raise ReproduceError("--decide chooses the claims and their episodes: give it without --claim, "
                                 "--report-only, --quick, --seeds or --episodes")
        try:
            ran = decide(args.paper, args.out, figures=args.figures, only=only, hours=args.decide,
                         workers=args.workers, backend=args.backend)
        except KeyboardInterrupt:
            raise KeyboardInterrupt(f"finished episodes kept under {args.out}/runs; rerun the same command to resume") from None
        print(f"ran {len(ran)} claims to their next look; wrote {args.out}/report.md, report.json and one PNG per figure")
        return 0
    try:
        _, results = reproduce(args.paper, args.out, figures=args.figures, quick=args.quick, seeds=seeds,
                               episodes=args.episodes,
                               only=only,
                               report_only=args.report_only, workers=args.workers, backend=args.backend,
                               claim=args.claim)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"finished episodes kept under {args.out}/runs; rerun the same command to resume") from None
    counts = verdict_counts(results)
    print(f"{len(results)} claims, {len(distinct_tests(results))} distinct tests: "
          + (", ".join(f"{n} {v}" for v, n in counts.items()) or "none"))
    print(f"wrote {args.out}/report.md, report.json and one PNG per figure")
    return 0


def _names(values: list | None) -> tuple | None:
    return tuple(values) if values else None
