"""Which of driveopt's safety machinery a faithful planner's collisions come from: the same episodes, the faithful
planner as it is and with one piece of driveopt's machinery given back at a time.

    python benchmarks/studies/faithful_ablation.py --planner vqvae-filter-faithful --scenario p2-four-lane-d3.0 \
        --seeds 42 123 --episodes 5 --out OUT.jsonl [--variants faithful stop-net ...] [--samples 1000] [--workers 2] \
        [--duration S] [--pairs SEED:EPISODE ...]

Variants (each the ``*-faithful`` planner of ``driveopt.faithful``, or its scenario, with one change):
- ``faithful``: as it is (the paper's ranking, the pick executed whatever its residual, no stop rows, no contact
  guard, constant-velocity prediction of the nearest neighbours);
- one piece of driveopt's machinery given back: ``stop-net`` (driveopt's stop rows in every batch and its fallback,
  a stop executed when no plan is feasible), ``feasibility-first`` (driveopt's ranking, feasible plans first),
  ``prediction`` (braking neighbours keep braking; the neighbours closest within the look-ahead rather than the
  nearest now), ``contact-guard`` (driveopt's brake-now guard at crawling speed);
- one of P2's authors' settings (``VQOptMain``: ``inferenceJax3.py``, ``utils/config.py``, ``model/DOptimizerJax3.py``
  and their highway-env copy): ``authors-command`` (the mean speed and steering of the plan's first eight nodes,
  passed to the simulator unscaled: :class:`driveopt.drivers.commands.FirstNodesMean`), ``authors-start`` (every plan
  starts at zero acceleration, lateral included), ``authors-ranking`` (their cost, its progress term gated by
  exp(-2 residual): :class:`driveopt.ranking.P2AuthorsRanking`), ``authors-25hz`` (their 25 Hz policy over a 100 Hz simulation),
  ``authors-cars`` (their cars: 4.0 x 1.4 m, upstream's 5.0 x 2.0 m; every car, so also the traffic's gaps),
  ``authors-spawn`` (their ego's start at 8 m/s and traffic spawned where upstream spawns it: other traffic), and
  ``authors`` (all of these but the ranking, and their ego's kinematics: no slip angle, heading rate v tan(steering) / (L / 2)).

Each record names its variant's definition (:func:`definition`): records of a planner defined otherwise (written
before it changed) are left in the file but neither reused nor summarised. Each episode is the bench episode of that seed and number (the same traffic for every variant, ``JobKey.env_seed``;
``--pairs``: only those seed and episode pairs), one JSON line per episode appended to ``--out`` as it ends: a rerun
skips the episodes the file holds (resumable), Ctrl-C and SIGTERM stop at once and keep the finished ones. At the
end, per variant: collisions, off-road episodes and the mean speed of the collision-free ones, over the episodes
every variant has.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import hashlib
import json
import multiprocessing
import sys
from pathlib import Path

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from driveopt.cli import stop_cleanly_on_signals
from driveopt.drivers.commands import P2_AUTHORS_COMMAND
from driveopt.cli.common import positive_int
from driveopt.errors import DriveoptError
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.store import JobKey
from driveopt.faithful import SUFFIX
from driveopt.fallback import Fallback
from driveopt.ranking import FeasibilityFirst, P2AuthorsRanking
from driveopt.registry import get_planner
from driveopt.sim import get_scenario

AUTHORS_CAR = (4.0, 1.4)  # [m] length, width of every car in P2's authors' highway-env copy (vehicle/kinematics.py)
AUTHORS_TIMING = {"policy_frequency": 25, "simulation_frequency": 100}  # [Hz] their utils/config.py
AUTHORS_SPAWN = {"ego_speed": 8.0, "min_initial_gap": 0.0, "min_spawn_gap": 0.0}  # the same group's highway-env copy
# (DiffProj highway_env/envs/highway_env.py): the ego spawns at 8 m/s and the traffic where upstream puts it (driveopt's
# scenarios keep every car 10 m ahead of the ego and 5 m bumper gaps; 0 separates only cars that overlap)


@dataclasses.dataclass(frozen=True)
class Variant:
    """What a variant changes: the planner's method, loop and maths sections, the scenario's fields, and the cars."""

    method: dict = dataclasses.field(default_factory=dict)
    loop: dict = dataclasses.field(default_factory=dict)
    maths: dict = dataclasses.field(default_factory=dict)  # PlannerConfig sections
    scenario: dict = dataclasses.field(default_factory=dict)
    cars: bool = False  # every car AUTHORS_CAR
    ego_kinematics: bool = False  # the ego moves as the authors' copy moves it (AuthorsEgo)


VARIANTS = {
    "faithful": Variant(),
    "stop-net": Variant(method={"fallback": Fallback()}, loop={"executes_infeasible": False}),
    "feasibility-first": Variant(method={"ranking": FeasibilityFirst()}),
    "prediction": Variant(loop={"braking_prediction": True, "approach_selection": True}),
    "contact-guard": Variant(loop={"contact_guard": True}),
    "authors-command": Variant(loop={"command": P2_AUTHORS_COMMAND}),
    "authors-start": Variant(loop={"measured_start": False}, maths={"qp": {"initial_lateral_acceleration": True}}),
    "authors-ranking": Variant(method={"ranking": P2AuthorsRanking()}),
    "authors-25hz": Variant(scenario=AUTHORS_TIMING),
    "authors-cars": Variant(cars=True),
    "authors-spawn": Variant(scenario=AUTHORS_SPAWN),
    "authors": Variant(loop={"command": P2_AUTHORS_COMMAND, "measured_start": False},
                       maths={"qp": {"initial_lateral_acceleration": True}}, scenario=AUTHORS_TIMING, cars=True,
                       ego_kinematics=True),
}


def variant_spec(planner: str, variant: str, samples: int):
    """The ``*-faithful`` ``planner`` with ``variant``'s planner changes, at ``samples`` samples."""
    if not planner.endswith(SUFFIX):
        raise DriveoptError(f"--planner must be a faithful planner (a name ending in {SUFFIX}), got {planner}")
    spec = get_planner(planner)
    change = VARIANTS[variant]
    return dataclasses.replace(spec, method=dataclasses.replace(spec.method, **change.method),
                               loop=dataclasses.replace(spec.loop, **change.loop),
                               config=spec.config.replace(**change.maths)).with_samples(samples)


class AuthorsEgo(Vehicle):
    """The ego as P2's authors' highway-env copy moves it: no slip angle, heading rate v tan(steering) / (L / 2)."""

    def step(self, dt: float) -> None:
        self.clip_actions()
        steering = self.action["steering"]
        self.position += self.speed * np.array([np.cos(self.heading), np.sin(self.heading)]) * dt
        if self.impact is not None:
            self.position += self.impact
            self.crashed = True
            self.impact = None
        self.heading += self.speed * np.tan(steering) / (self.LENGTH / 2) * dt
        self.speed += self.action["acceleration"] * dt
        self.on_state_update()


class WithAuthorsCars:
    """``driver`` on a road whose cars are the authors' (:data:`AUTHORS_CAR`), the ego moving as theirs if
    ``ego_kinematics``: the cars are resized after the env's reset, before the driver reads them."""

    def __init__(self, driver, ego_kinematics: bool) -> None:
        self.driver, self.ego_kinematics = driver, ego_kinematics

    def __getattr__(self, name: str):
        return getattr(self.driver, name)

    def reset(self, env, scenario, seed: int) -> None:
        sim = env.unwrapped
        length, width = AUTHORS_CAR
        for vehicle in sim.road.vehicles:
            vehicle.LENGTH, vehicle.WIDTH = length, width
            vehicle.diagonal = float(np.hypot(length, width))
        if self.ego_kinematics:
            sim.vehicle.__class__ = AuthorsEgo
        self.driver.reset(env, scenario, seed)


def definition(planner: str, variant: str, samples: int) -> str:
    """12 hex digits naming what ``variant`` of ``planner`` runs (its maths, method and loop, and the variant's scenario
    and car changes): a record of another definition (the planner changed since) is neither reused nor summarised."""
    spec, change = variant_spec(planner, variant, samples), VARIANTS[variant]
    text = repr((spec.config, spec.method, spec.loop, sorted(change.scenario.items()), change.cars, change.ego_kinematics))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def run_episode(scenario: str, planner: str, variant: str, samples: int, seed: int, episode: int,
                duration: float | None = None) -> dict:
    change = VARIANTS[variant]
    driver = variant_spec(planner, variant, samples).driver()
    if change.cars:
        driver = WithAuthorsCars(driver, change.ego_kinematics)
    rollout = Rollout(get_scenario(scenario).replace(**change.scenario), driver,
                      JobKey(scenario, planner, seed, episode).env_seed, duration=duration)
    for _ in rollout:
        pass
    done = rollout.episode
    return {"scenario": scenario, "planner": planner, "variant": variant,
            "definition": definition(planner, variant, samples), "samples": samples, "seed": seed,
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
    current = {v: definition(args.planner, v, args.samples) for v in args.variants}
    records = [r for r in records if r["planner"] == args.planner and r["scenario"] == args.scenario
               and r["samples"] == args.samples and r["duration"] == args.duration
               and r.get("definition") == current.get(r["variant"])]
    done = {_key(r) for r in records}
    todo = [(v, s, e) for v in args.variants for s, e in pairs if (v, s, e) not in done]  # a variant's episodes together
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
