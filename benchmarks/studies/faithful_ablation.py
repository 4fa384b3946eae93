"""Which of driveopt's safety machinery a faithful planner's collisions come from: the same episodes, the faithful
planner as it is and with one piece of driveopt's machinery given back at a time.

    python benchmarks/studies/faithful_ablation.py --planner vqvae-filter-faithful --scenario p2-four-lane-d3.0 \
        --seeds 42 123 --episodes 5 --out OUT.jsonl [--variants faithful stop-net ...] [--samples 1000] [--workers 2] \
        [--duration S] [--pairs SEED:EPISODE ...]

Variants (each the ``*-faithful`` planner of ``driveopt.faithful`` with one change):
- ``faithful``: as it is (the paper's ranking, the pick executed whatever its residual, no stop rows, no contact
  guard, constant-velocity prediction of the nearest neighbours);
- ``stop-net``: driveopt's stop rows in every batch and its fallback (a stop executed when no plan is feasible);
- ``feasibility-first``: driveopt's ranking (feasible plans first) instead of the paper's cost + residual;
- ``prediction``: driveopt's neighbour prediction (braking neighbours keep braking; the neighbours closest within the
  look-ahead rather than the nearest now);
- ``contact-guard``: driveopt's brake-now guard at crawling speed.

Each episode is the bench episode of that seed and number (the same traffic for every variant, ``JobKey.env_seed``;
``--pairs``: only those seed and episode pairs), one JSON line per episode appended to ``--out`` as it ends: a rerun
skips the episodes the file holds (resumable), Ctrl-C and SIGTERM stop at once and keep the finished ones. At the
end, per variant: collisions, off-road episodes and the mean speed of the collision-free ones, over the episodes
every variant has.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import json
import multiprocessing
import sys
from pathlib import Path

from driveopt.cli import stop_cleanly_on_signals
from driveopt.cli.common import positive_int
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.store import JobKey
from driveopt.faithful import SUFFIX
from driveopt.fallback import Fallback
from driveopt.ranking import FeasibilityFirst
from driveopt.registry import get_planner
from driveopt.sim import get_scenario

VARIANTS = {
    "faithful": ({}, {}),  # (the method's fields, the loop's fields) given back
    "stop-net": ({"fallback": Fallback()}, {"executes_infeasible": False}),
    "feasibility-first": ({"ranking": FeasibilityFirst()}, {}),
    "prediction": ({}, {"braking_prediction": True, "approach_selection": True}),
    "contact-guard": ({}, {"contact_guard": True}),
}


def variant_spec(planner: str, variant: str, samples: int):
    """The ``*-faithful`` ``planner`` with ``variant``'s piece of driveopt's machinery, at ``samples`` samples."""
    if not planner.endswith(SUFFIX):
        raise DriveoptError(f"--planner must be a faithful planner (a name ending in {SUFFIX}), got {planner}")
    spec = get_planner(planner)
    method, loop = VARIANTS[variant]
    return dataclasses.replace(spec, method=dataclasses.replace(spec.method, **method),
                               loop=dataclasses.replace(spec.loop, **loop)).with_samples(samples)


def run_episode(scenario: str, planner: str, variant: str, samples: int, seed: int, episode: int,
                duration: float | None = None) -> dict:
    spec = variant_spec(planner, variant, samples)
    rollout = Rollout(get_scenario(scenario), spec.driver(), JobKey(scenario, planner, seed, episode).env_seed,
                      duration=duration)
    for _ in rollout:
        pass
    done = rollout.episode
    return {"scenario": scenario, "planner": planner, "variant": variant, "samples": samples, "seed": seed,
            "episode": episode, "duration": duration, "collided": bool(done.collided), "off_road": bool(done.off_road),
            "end_s": round(float(done.sim_duration), 2), "mean_speed": round(float(done.mean_speed), 3)}


def _key(record: dict) -> tuple:
    return record["variant"], record["seed"], record["episode"]


def summarise(records: list[dict], variants: list[str]) -> dict[str, dict]:
    """Per variant, over the (seed, episode) pairs every variant has: episodes, collisions, off-road episodes, mean
    speed [m/s] of the episodes that neither collided nor left the road (None if there is none)."""
    by_variant = {v: {(r["seed"], r["episode"]): r for r in records if r["variant"] == v} for v in variants}
    common = set.intersection(*(set(episodes) for episodes in by_variant.values())) if by_variant else set()
    summary = {}
    for variant, episodes in by_variant.items():
        rows = [episodes[k] for k in sorted(common)]
        clean = [r["mean_speed"] for r in rows if not r["collided"] and not r["off_road"]]
        summary[variant] = {"episodes": len(rows), "collisions": sum(r["collided"] for r in rows),
                            "off_road": sum(r["off_road"] for r in rows),
                            "mean_speed": round(sum(clean) / len(clean), 3) if clean else None,
                            "collided_episodes": [[r["seed"], r["episode"]] for r in rows if r["collided"]]}
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="faithful_ablation.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", required=True, help="a *-faithful planner")
    parser.add_argument("--scenario", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[42, 123])
    parser.add_argument("--episodes", type=positive_int, default=5, help="bench episodes 0..N-1 of each seed")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--samples", type=positive_int, default=1000, help="samples per sampler iteration")
    parser.add_argument("--workers", type=positive_int, default=2)
    parser.add_argument("--pairs", nargs="+", metavar="SEED:EPISODE", help="only these episodes (instead of --seeds and --episodes)")
    parser.add_argument("--duration", type=float, help="[s] stop every episode here (default: the scenario's)")
    parser.add_argument("--out", required=True, help="JSON lines, one per episode (appended; a rerun resumes)")
    args = parser.parse_args(argv)
    if args.duration is not None and not args.duration > 0:
        parser.error("--duration must be > 0")
    try:
        pairs = ([tuple(int(n) for n in pair.split(":")) for pair in args.pairs] if args.pairs
                 else [(s, e) for s in args.seeds for e in range(args.episodes)])
    except ValueError:
        pairs = []
    if not pairs or any(len(pair) != 2 or pair[1] < 0 for pair in pairs):
        parser.error(f"--pairs takes SEED:EPISODE pairs with EPISODE >= 0, got {' '.join(args.pairs)}")
    try:
        variant_spec(args.planner, args.variants[0], args.samples)
        get_scenario(args.scenario)
    except (DriveoptError, KeyError, ValueError) as exc:
        parser.error(str(exc))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    records = [json.loads(line) for line in out.read_text().splitlines() if line.strip()] if out.exists() else []
    records = [r for r in records if r["planner"] == args.planner and r["scenario"] == args.scenario
               and r["samples"] == args.samples and r["duration"] == args.duration]
    done = {_key(r) for r in records}
    todo = [(v, s, e) for s, e in pairs for v in args.variants if (v, s, e) not in done]
    print(f"{len(todo)} episodes to run ({len(done)} in {out})", flush=True)
    stop_cleanly_on_signals()
    pool = concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = {pool.submit(run_episode, args.scenario, args.planner, v, args.samples, s, e, args.duration): (v, s, e)
                   for v, s, e in todo}
        for n, future in enumerate(concurrent.futures.as_completed(futures), 1):
            record = future.result()
            with out.open("a") as f:
                f.write(json.dumps(record) + "\n")
            records.append(record)
            print(f"[{n}/{len(todo)}] {record['variant']} seed {record['seed']} episode {record['episode']}: "
                  f"{'collided' if record['collided'] else 'off road' if record['off_road'] else 'clean'} at "
                  f"{record['end_s']} s, {record['mean_speed']} m/s", flush=True)
    except KeyboardInterrupt:
        workers = list((pool._processes or {}).values())  # the running episodes stop with their workers
        pool.shutdown(wait=False, cancel_futures=True)
        for process in workers:
            process.terminate()
        print(f"stopped; {out} keeps the finished episodes", file=sys.stderr)
        return 130
    pool.shutdown()
    summary = summarise([r for r in records if (r["seed"], r["episode"]) in set(pairs)], args.variants)
    for variant, row in summary.items():
        print(f"{variant}: {row['collisions']}/{row['episodes']} collided, {row['off_road']} off road, "
              f"{row['mean_speed']} m/s (collision-free)")
    summary_path = out.with_suffix(".summary.json")
    summary_path.write_text(json.dumps({"planner": args.planner, "scenario": args.scenario, "samples": args.samples,
                                        "pairs": pairs, "variants": summary}, indent=1))
    print(f"wrote {summary_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
