"""A planner-configuration change against the planner's own configuration, in closed loop on the same episodes: does
it drive as safely and as quickly?

    python benchmarks/studies/setting_ab.py --config C.json --out DIR [--planner bilevel] [--samples N]
        [--scenarios four-lane-d3.0 two-lane-d2.5] [--episodes 50] [--seed 42]
        [--upstream highway-v0] [--upstream-episodes 20] [--upstream-seed 0] [--workers 2]

``driveopt bench`` drives ``--planner`` on each scenario with its own configuration (``DIR/own``) and with the
overrides of ``--config`` (a JSON file of nested sections, as for ``driveopt bench --config``; ``DIR/changed``), on
the same traffic seeds (a config that sets ``sampler.num_samples`` drives the changed side at that count);
``benchmarks/studies/upstream_roads.py`` drives each ``--upstream`` env through
``driveopt.Controller`` both ways (``DIR/upstream-own``, ``DIR/upstream-changed``; ``--upstream-episodes`` resets
from ``--upstream-seed`` on: from 20, resets no earlier change was tuned on). Every part resumes where it stopped.
Then each road's pairs are judged by the rule a setting must pass before it becomes a default:

- collisions no worse: the changed side collided in at most ``ceil(pairs / 50)`` more episodes than its own side, and
  exact McNemar on the discordant pairs does not find it worse (two-sided p >= 0.05 where it collided more);
- speed within 2 %: the mean speed over the pairs where neither side collided is at least 0.98 of the own side's.

A side that already holds records when the run starts (stopped earlier, or copied from another run) is resumed only
if its records repeat on this machine: the first road's first episode is driven again into a scratch folder and must
end as recorded (collision, off-road, steps and mean speed to the last digit). Episodes of the same code need not
repeat across machines (upstream ``highway-v0``'s did not on two of the same make), and an A/B whose sides ran on
two machines would measure the machines too.

``DIR/verdict.json`` holds per road: pairs, collisions each way, discordant pairs, the McNemar p-value, off-road
episodes, mean speeds, median plan time [ms] each way, and whether it passed; and overall whether every road passed.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from driveopt.cli.common import positive_int
from driveopt.experiments.paired_stats import mcnemar_exact
from driveopt.experiments.store import load_folder
from driveopt.files import write_json

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package import below
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.studies import upstream_roads  # noqa: E402

ALPHA = 0.05
SPEED_SHARE = 0.98  # the changed side's mean speed at least this share of the own side's


def judge(pairs: list[tuple[dict, dict]]) -> dict:
    """The rule of the module docstring on (own, changed) episode records of one road, each with ``collided``,
    ``off_road`` and ``mean_speed`` (``plan_ms`` or ``plan_ms_median`` for the time)."""
    own_hits = sum(a["collided"] for a, _ in pairs)
    changed_hits = sum(b["collided"] for _, b in pairs)
    only_own = sum(a["collided"] and not b["collided"] for a, b in pairs)
    only_changed = sum(b["collided"] and not a["collided"] for a, b in pairs)
    p = mcnemar_exact(only_changed, only_own)
    allowed = math.ceil(len(pairs) / 50)
    collisions_ok = changed_hits <= own_hits + allowed and not (only_changed > only_own and p < ALPHA)
    clean = [(a, b) for a, b in pairs if not a["collided"] and not b["collided"]]
    own_speed = float(np.mean([a["mean_speed"] for a, _ in clean])) if clean else math.nan
    changed_speed = float(np.mean([b["mean_speed"] for _, b in clean])) if clean else math.nan
    speed_ok = bool(clean) and changed_speed >= SPEED_SHARE * own_speed

    def plan_ms(record):
        return record["plan_ms_median"] if "plan_ms_median" in record else float(np.median(record["plan_ms"]))

    return {"pairs": len(pairs), "collisions": [own_hits, changed_hits], "only_own": only_own,
            "only_changed": only_changed, "mcnemar_p": p, "collisions_allowed_extra": allowed,
            "off_road": [sum(a["off_road"] for a, _ in pairs), sum(b["off_road"] for _, b in pairs)],
            "clean_pairs": len(clean), "mean_speed": [own_speed, changed_speed],
            "speed_ratio": changed_speed / own_speed if clean else math.nan,
            "plan_ms_median": [float(np.median([plan_ms(a) for a, _ in pairs])),
                               float(np.median([plan_ms(b) for _, b in pairs]))],
            "collisions_ok": collisions_ok, "speed_ok": speed_ok, "passed": collisions_ok and speed_ok}


def bench_pairs(out: Path, scenario: str, planner: str) -> list[tuple[dict, dict]]:
    def episodes(side):
        _, records = load_folder(out / side)  # checked against the side's spec.json
        return {(r["seed"], r["episode"]): r for r in records if r["scenario"] == scenario and r["planner"] == planner}

    own, changed = episodes("own"), episodes("changed")
    return [(own[key], changed[key]) for key in sorted(own.keys() & changed.keys())]


def upstream_pairs(out: Path, env: str, planner: str, episodes: int, first: int = 0) -> list[tuple[dict, dict]]:
    def records(side):
        path = out / f"upstream-{side}" / "episodes.jsonl"
        lines = path.read_text().splitlines() if path.exists() else []
        return {r["seed"]: r for r in map(json.loads, lines) if r["env"] == env and r["planner"] == planner
                and "refused" not in r}

    own, changed = records("own"), records("changed")
    return [(own[s], changed[s]) for s in range(first, first + episodes) if s in own and s in changed]  # upstream_roads' resets


REPEATED_FIELDS = ("collided", "off_road", "steps", "mean_speed")


def first_record(folder: Path, road: str, planner: str, first_seed: int, upstream: bool) -> dict | None:
    """The record of ``road``'s first episode of ``planner`` in the side folder ``folder`` (bench: episode 0 of the
    seed; upstream: the reset ``first_seed``), None when it holds none."""
    path = folder / "episodes.jsonl"
    if not path.exists():
        return None
    for record in map(json.loads, path.read_text().splitlines()):
        if upstream and (record.get("env"), record.get("planner"), record.get("seed")) == (road, planner, first_seed) \
                and "refused" not in record:
            return record
        if not upstream and (record.get("scenario"), record.get("planner"), record.get("seed"), record.get("episode")) \
                == (road, planner, first_seed, 0):
            return record
    return None


def differences(recorded: dict, driven: dict) -> list[str]:
    """The fields of :data:`REPEATED_FIELDS` where an episode driven again ends otherwise than recorded."""
    return [f"{name} {recorded.get(name)!r} recorded, {driven.get(name)!r} now" for name in REPEATED_FIELDS
            if recorded.get(name) != driven.get(name)]


class Part(NamedTuple):
    """One side's folder of bench or upstream episodes and how to drive them: ``drive(out, samples, extra, roads,
    episodes)``; ``first_seed``: the bench seed or the first upstream reset."""

    folder: str
    samples: int
    extra: list[str]
    drive: Callable[[Path, int, list[str], list[str], int], None]
    roads: list[str]
    episodes: int
    first_seed: int
    upstream: bool


def refuse_unless_repeated(out: Path, planner: str, part: Part) -> None:
    """SystemExit unless ``part``'s folder holds no record of its first road's first episode or that episode, driven
    again here into a scratch folder, ends as recorded (:func:`differences`)."""
    road = part.roads[0]
    recorded = first_record(out / part.folder, road, planner, part.first_seed, part.upstream)
    if recorded is None:
        return
    with tempfile.TemporaryDirectory() as scratch:
        part.drive(Path(scratch) / "again", part.samples, part.extra, [road], 1)
        driven = first_record(Path(scratch) / "again", road, planner, part.first_seed, part.upstream)
    changed = differences(recorded, driven or {})
    if changed:
        raise SystemExit(f"setting_ab: {out / part.folder}'s records do not repeat on this machine ({road}'s first "
                         f"episode driven again: {'; '.join(changed)}); drive both sides on one machine (move the "
                         "folder away)")
    print(f"{out / part.folder}: {road}'s first episode repeats on this machine", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, required=True, help="the changed side's overrides (JSON file)")
    parser.add_argument("--out", type=Path, required=True, help="folder of both sides' records and verdict.json")
    parser.add_argument("--planner", default="bilevel")
    parser.add_argument("--samples", type=positive_int, help="samples per batch (default: the planner's own)")
    parser.add_argument("--scenarios", nargs="*", default=["four-lane-d3.0", "two-lane-d2.5"])
    parser.add_argument("--episodes", type=positive_int, default=50, help="episodes per scenario and side")
    parser.add_argument("--seed", type=int, default=42, help="bench traffic seed")
    parser.add_argument("--upstream", nargs="*", default=["highway-v0"], choices=list(upstream_roads.ENVS))
    parser.add_argument("--upstream-episodes", type=positive_int, default=20)
    parser.add_argument("--upstream-seed", type=int, default=0, help="the upstream envs' first reset seed")
    parser.add_argument("--workers", type=positive_int, default=2, help="parallel bench episodes")
    args = parser.parse_args(argv)
    from driveopt.errors import DriveoptError
    from driveopt.registry import get_optimiser

    try:  # a bad planner, file, section, field or value is refused here, before any driving
        spec = get_optimiser(args.planner)
        overrides = json.loads(args.config.read_text())
        spec.with_overrides(**overrides)
    except (DriveoptError, OSError, ValueError, TypeError) as exc:
        parser.error(str(exc))
    samples = args.samples if args.samples is not None else spec.config.sampler.num_samples
    changed_samples = (overrides.get("sampler") or {}).get("num_samples", samples)  # a change of the sample count
    common = ["--planners", args.planner, "--seeds", str(args.seed)]
    sides = (("own", samples, []), ("changed", changed_samples, ["--config", str(args.config.resolve())]))

    def drive_bench(out: Path, count: int, extra: list[str], scenarios: list[str], episodes: int) -> None:
        subprocess.run([sys.executable, "-m", "driveopt.cli", "bench", "--scenarios", *scenarios, *common,
                        "--episodes", str(episodes), "--workers", str(args.workers), "--samples", str(count), *extra,
                        "--out", str(out)], check=True)

    def drive_upstream(out: Path, count: int, extra: list[str], envs: list[str], episodes: int) -> None:
        upstream_roads.main(["--out", str(out), "--envs", *envs, "--planners", args.planner, "--episodes",
                             str(episodes), "--seed", str(args.upstream_seed), "--samples", str(count), *extra])

    parts = [Part(side, count, extra, drive_bench, args.scenarios, args.episodes, args.seed, False)
             for side, count, extra in sides if args.scenarios]
    parts += [Part(f"upstream-{side}", count, extra, drive_upstream, args.upstream, args.upstream_episodes,
                   args.upstream_seed, True) for side, count, extra in sides if args.upstream]
    for part in parts:
        refuse_unless_repeated(args.out, args.planner, part)
    for part in parts:
        part.drive(args.out / part.folder, part.samples, part.extra, part.roads, part.episodes)
    roads = {name: judge(bench_pairs(args.out, name, args.planner)) for name in args.scenarios}
    roads.update({name: judge(upstream_pairs(args.out, name, args.planner, args.upstream_episodes, args.upstream_seed))
                  for name in args.upstream})
    verdict = {"command": "python benchmarks/studies/setting_ab.py " + " ".join(argv if argv is not None else sys.argv[1:]),
               "planner": args.planner, "samples": samples, "changed_samples": changed_samples, "config": overrides,
               "roads": roads,
               "passed": all(road["passed"] for road in roads.values())}
    write_json(args.out / "verdict.json", verdict)
    for name, road in roads.items():
        print(f"{name}: {road['pairs']} pairs, collisions {road['collisions'][0]} -> {road['collisions'][1]} "
              f"(McNemar p {road['mcnemar_p']:.3g}), speed {road['mean_speed'][0]:.2f} -> {road['mean_speed'][1]:.2f} "
              f"m/s, plan {road['plan_ms_median'][0]:.0f} -> {road['plan_ms_median'][1]:.0f} ms: "
              + ("passed" if road["passed"] else "failed"))
    print("passed" if verdict["passed"] else "failed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
