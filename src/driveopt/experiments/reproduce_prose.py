"""The numbers the prose around the reproduction reports quotes, written from the reports' ``report.json``.

``docs/reproduction/README.md`` holds blocks between ``<!-- generated: NAME -->`` and ``<!-- end generated -->``; each is
the text of :data:`BLOCKS` ``[NAME]`` over the committed reports, so a report regenerated from new records rewrites
the sentence that quotes it (:func:`update`, run by ``benchmarks/studies/reproduce_campaign.sh --report``) and a test
checks that the committed prose equals what the committed reports say. :func:`readme_sentence` is the sentence the
repository's README.md quotes.

    python -m driveopt.experiments.reproduce_prose docs/reproduction/README.md benchmarks/results/reproduction
"""

from __future__ import annotations

import json
import re
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

HEADLINE = "p2-four-lane-d3.0"
FAITHFUL_PIPELINES = ("vqvae-filter-faithful", "cvae-multipliers-faithful", "cvae-filter-faithful")
DRIVEOPT_PIPELINES = ("vqvae-filter", "cvae-multipliers", "cvae-filter")
MARK = re.compile(r"<!-- generated: (?P<name>[a-z0-9-]+) -->(?P<body>.*?)<!-- end generated -->", re.S)


def load(records: str | Path) -> dict[str, dict[str, Any]]:
    """``{paper: report.json}`` of ``records/p1`` and ``records/p2``."""
    return {paper: json.loads((Path(records) / paper / "report.json").read_text()) for paper in ("p1", "p2")}


def _claims(report: dict[str, Any]) -> list[dict[str, Any]]:
    return [c for f in report["figures"] for c in f["claims"]]


def _collided(report: dict[str, Any], planners: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    """{planner: (collisions, pairs)} on P2 Fig. 7's headline road, from the rows of ``planners[0]`` against the others;
    a planner whose row has no pair is left out."""
    rows = [c for c in _claims(report) if c["figure"] == "fig7" and c["scenario"] == HEADLINE
            and c["metric"] == "collisions" and c["arm"]["planner"] == planners[0]]
    counts: dict[str, tuple[int, int]] = {}
    for c in rows:
        if c["baseline"]["planner"] in planners and c["pairs"]:
            counts[planners[0]] = (c["arm"]["collisions"], c["pairs"])
            counts[c["baseline"]["planner"]] = (c["baseline"]["collisions"], c["pairs"])
    if planners[0] not in counts:
        raise ValueError(f"P2's report has no {HEADLINE} collision row of {planners[0]} with a pair")
    return counts


def _and(values: list[Any]) -> str:
    return ", ".join(map(str, values[:-1])) + f" and {values[-1]}" if len(values) > 1 else str(values[0])


def p2_faithful_headline(reports: dict[str, dict[str, Any]]) -> str:
    """How often P2's pipelines as their authors ran them, and driveopt's, collide on P2 Fig. 7's headline road."""
    faithful = _collided(reports["p2"], FAITHFUL_PIPELINES)
    ours = _collided(reports["p2"], DRIVEOPT_PIPELINES)
    shown = [f"`{planner}` {n} of {pairs}" for planner, (n, pairs) in faithful.items()]
    missing = [f"`{planner}`" for planner in FAITHFUL_PIPELINES if planner not in faithful]
    text = f"{_and(shown)} headline episodes against P2's few percent"
    if missing:
        text += f" ({_and(missing)} not yet run on this code)"
    return text + f"; driveopt's pipelines {_and([f'{n} of {pairs}' for n, pairs in ours.values()])}"


def _tally(report: dict[str, Any]) -> str:
    return ", ".join(f"{n} {verdict}" for verdict, n in report["verdicts"].items())


def verdict_tallies(reports: dict[str, dict[str, Any]]) -> str:
    """The verdicts of both reports, counted once per distinct test."""
    return "; ".join(f"{paper.upper()}: {reports[paper]['tests']} distinct tests, {_tally(reports[paper])}"
                     for paper in ("p1", "p2"))


def _pairs(reports: dict[str, dict[str, Any]]) -> tuple[int, int, int]:
    """(the most common pairs of a claim, the most pairs of any claim, the full protocol's pairs)."""
    pairs = [c["pairs"] for paper in ("p1", "p2") for c in _claims(reports[paper])]
    full = max(c["full_pairs"] for paper in ("p1", "p2") for c in _claims(reports[paper]))
    return Counter(pairs).most_common(1)[0][0], max(pairs), full


def _question(report: dict[str, Any]) -> str:
    rows = {q["metric"]: q for q in report["questions"]}
    collisions, speed, plan = rows["collisions"], rows["speed"], rows["plan time"]
    return (f"P2's learned filter against the plain one, {collisions['pairs']} pairs: {collisions['verdict']} in collisions "
            f"({collisions['arm']['collisions']} against {collisions['baseline']['collisions']}), speed "
            f"{speed['verdict']} ({speed['arm']['speed']:.2f} against {speed['baseline']['speed']:.2f} m/s), plan "
            f"time {plan['verdict']} ({plan['plan_pairs']} pairs on one processor, {plan['plan_difference']:+.1f} ms)")


def readme_sentence(reports: dict[str, dict[str, Any]]) -> str:
    """The repository README's sentences on the reproduction, from both reports."""
    most, highest, full = _pairs(reports)
    return (f"Every claim of both papers as a paired, like-for-like test on seeds 42 and 123, judged by `driveopt "
            f"reproduce` on the size the paper states, at sequential looks with one primary claim per figure "
            f"({verdict_tallies(reports)}; most claims at {most} of the protocol's {full} pairs, the most-run at "
            f"{highest}): [P1](docs/reproduction/p1-claims.md), [P2](docs/reproduction/p2-claims.md). "
            f"{_question(reports['p2'])}.")


def quick_runs(paper: str) -> str:
    """What ``driveopt reproduce PAPER --quick`` runs: its episodes, bench folders and claims, from the protocols."""
    from driveopt.experiments.protocols import figures_of
    from driveopt.experiments.reproduce import bench_runs

    figures = figures_of(paper, None, quick=True)
    runs = bench_runs(figures, Path("."))
    episodes = {(run.path, job) for run in runs for job in run.spec.jobs()}
    durations = {run.spec.options.get("duration") for run in runs}
    length = f" of {durations.pop():g} s" if len(durations) == 1 and None not in durations else ""
    claims = sum(len(figure.claims) for figure in figures)
    return f"{len(episodes)} episodes{length}, {len({run.path for run in runs})} bench folders, {claims} claims"


BLOCKS: dict[str, Callable[[dict[str, dict[str, Any]]], str]] = {
    "p2-faithful-headline": p2_faithful_headline,
    "verdict-tallies": verdict_tallies,
    "quick-p1": lambda reports: quick_runs("p1"),
    "quick-p2": lambda reports: quick_runs("p2"),
}


def render(text: str, reports: dict[str, dict[str, Any]]) -> str:
    """``text`` with every generated block rewritten from ``reports``; ValueError for a block of unknown name."""
    def block(match: re.Match[str]) -> str:
        name = match["name"]
        if name not in BLOCKS:
            raise ValueError(f"unknown generated block {name!r}; known: {', '.join(BLOCKS)}")
        return f"<!-- generated: {name} -->{BLOCKS[name](reports)}<!-- end generated -->"

    return MARK.sub(block, text)


def update(doc: str | Path, records: str | Path) -> bool:
    """Rewrite ``doc``'s generated blocks from the reports under ``records``; whether it changed."""
    path = Path(doc)
    old = path.read_text()
    new = render(old, load(records))
    if new != old:
        path.write_text(new)
    return new != old


if __name__ == "__main__":
    changed = update(sys.argv[1], sys.argv[2])
    print(f"{sys.argv[1]}: {'rewritten' if changed else 'unchanged'}")
