"""driveopt's controller and highway-env's IDM on upstream highway-env's own envs: collisions, off-road, speed.

    python benchmarks/studies/upstream_roads.py --out benchmarks/results/upstream-roads [--episodes 20] [--samples 250]
        [--envs highway-v0 racetrack-v0 ...] [--planners bilevel idm] [--seed 0] [--duration 20] [--config C.json]
        [--hold-actions] [--plan-frequency HZ]

Each episode makes the env with ``driveopt.gym_make`` (``gymnasium.make`` with rewards for array actions) and
``ContinuousAction`` (default traffic; the settings of :data:`ENVS` make every env last the duration: an env config's
``duration`` is ``--duration``; lane-keeping-v0 stops at gymnasium's 200 steps, 20 s), resets it with seed
``seed + episode`` and drives it through :class:`driveopt.Controller` (``idm``: highway-env's IDM/MOBIL vehicle takes
the ego's place; ``--config``: planner-config overrides of the optimisers, a JSON file as for ``driveopt bench
--config``) at the ego lane's speed limit as desired speed, for ``--duration`` seconds or until the env ends the
episode. The optimisers' plans are tracked at every simulation step of a policy period (``Controller``'s
``track_within_period``; their records say ``tracked_within_period`` where the env holds an action for more
than one simulation step); ``--hold-actions``: each action held for the period
(the records before the controller tracked within it); ``--plan-frequency HZ``: the optimisers plan HZ times a second
(``Controller``'s ``plan_frequency``; default its own, 5 Hz) on the envs whose policy frequency is lower and whose
simulation frequency it divides (their records say ``plan_frequency``), each plan tracked until the next; elsewhere
once per policy step (``--plan-frequency 1``: once per policy step at upstream's 1 Hz envs). An env the controller refuses at reset (``RoadFrameError``: a road it cannot represent; ``ControllerError``:
parking-v0's goal pose) is recorded as refused with the message. Every episode is one line of
``OUT/episodes.jsonl`` (a rerun skips those done: resumable); ``OUT/table.md`` is docs/controller.md's table of
them; ``OUT/summary.json`` gives, per env and planner (every
one recorded with these settings, not only this run's), the episodes, collisions, off-road episodes, refusals,
arrivals, the mean speed over the episodes without collision and the median over episodes of each episode's median
planning time (wall clock of the machine the episodes ran on: see its load).
An episode *arrived* when the env says so at its end (its ``is_success`` info: exit-v0's, in the exit lane or on the
exit road; intersection-v0's ``has_arrived``) or, on a route (the controller's: the task's, e.g. roundabout-v0's
exit, u-turn-v0's road back), when the ego was on the route's last road at a policy step (the road may lead on:
roundabout-v0's exit road into the road beyond it); null without a destination (highway-v0, the racetracks, lane-keeping-v0 ...). :data:`ENVS` holds every env of highway-env 1.12.1
but its variants of the same roads (``-v1``: connected-lane neighbours; the multi-agent intersection, the parking
variants); ``merge-generic-v0`` and ``roundabout-generic-v0`` at their default settings.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from pathlib import Path

import numpy as np

ENVS = {  # env id -> (gymnasium.make config besides ContinuousAction, make kwargs)
    "highway-v0": ({"duration": 20}, {}),
    "highway-fast-v0": ({"duration": 20}, {}),  # highway-v0 with 3 lanes, 20 cars and 5 Hz simulation
    "racetrack-v0": ({}, {}),
    "racetrack-oval-v0": ({}, {}),
    "exit-v0": ({"duration": 20}, {}),
    "merge-v0": ({}, {}),  # upstream ends the episode past x = 370 m
    "two-way-v0": ({"observation": {"type": "Kinematics"}}, {"max_episode_steps": 20}),
    "roundabout-v0": ({}, {}),
    "intersection-v0": ({}, {}),
    "u-turn-v0": ({"observation": {"type": "Kinematics"}, "duration": 20}, {}),  # upstream's TTC grid reads MDPVehicle
    "racetrack-large-v0": ({}, {}),
    "lane-keeping-v0": ({"observation": {"type": "Kinematics"}}, {}),  # upstream's observation reads BicycleVehicle
    "merge-generic-v0": ({}, {}),  # ends past its merge, as merge-v0
    "roundabout-generic-v0": ({}, {}),  # upstream routes its ego to the exit "nxs", as roundabout-v0's
    "parking-v0": ({}, {}),  # refused at reset: a goal pose, no lane to follow
}
ROUTED_ROWS = {  # a row of the table driving an env along a route given to the controller: row -> (env id, route)
    "exit-v0, straight on": ("exit-v0", ("0", "1", "2", "3")),  # past the exit, the road exit-v0 does not reward
}
ROWS = [*ENVS, *ROUTED_ROWS]  # the table's rows, in order (an env's routed rows after every env)
ROUTE_REACHED = "arrived: the route's last road reached"
SETUP = {"exit-v0": "route to the exit, arrived as upstream's success", "roundabout-v0": ROUTE_REACHED,
         "u-turn-v0": ROUTE_REACHED, "roundabout-generic-v0": ROUTE_REACHED, **{row: ROUTE_REACHED for row in ROUTED_ROWS}}
"""Envs whose episodes changed since the records began (exit-v0 drove straight on, then counted arrivals on the exit road
only; the route envs counted the ego ending on the route's last road, not one that drove on past it): a record counts
only with its env's setup, older ones are driven again."""


def make_env(env_id: str, duration: float | None = None):
    """``env_id`` as the table makes it (``driveopt.gym_make``, ``ContinuousAction``, :data:`ENVS`' settings), lasting
    ``duration`` [s] where its settings set one (None: theirs)."""
    import driveopt

    config, kwargs = ENVS[env_id]
    if duration is not None and "duration" in config:
        config = {**config, "duration": duration}
    return driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}, **config}, **kwargs)


def run_episode(env_id: str, planner: str, seed: int, samples: int, duration: float,
                planner_config: dict | None = None, within_period: bool = True, plan_frequency: float | None = None,
                time_gap: float = 0.0) -> dict:
    """One episode's record; ``env_id``: an env of :data:`ENVS` or a row of :data:`ROUTED_ROWS`; ``plan_frequency``
    [Hz]: the optimisers' (``Controller``'s ``plan_frequency``; None: its default); ``time_gap`` [s]: the
    optimisers' (``Controller``'s)."""
    import driveopt
    from driveopt.controller import ControllerError
    from driveopt.sim.road_frame import RoadFrameError

    row = env_id
    env_id, given_route = ROUTED_ROWS.get(row, (row, None))
    env = make_env(env_id, duration)
    record = {"env": row, "planner": planner, "seed": seed, **({"setup": SETUP[row]} if row in SETUP else {})}
    try:
        env.reset(seed=seed)
        optimiser = planner != "idm"
        controller = driveopt.Controller(planner, samples=samples if optimiser else None,
                                         config=planner_config if optimiser else None,
                                         track_within_period=within_period, route=given_route,
                                         plan_frequency=plan_frequency if optimiser else None,
                                         time_gap=time_gap if optimiser else 0.0)
        try:
            controller.reset(env, seed=seed)
        except (RoadFrameError, ControllerError) as exc:
            return {**record, "refused": str(exc)}
        sim = env.unwrapped
        steps = round(duration * sim.config["policy_frequency"])
        speeds, statuses, plan_ms = [], Counter(), []
        collided = off_road = False
        info: dict = {}
        route = controller.task.route
        reached = False  # the route's last road at a policy step
        start = time.perf_counter()
        for _ in range(steps):
            try:  # the controller replans inside env.step too (within the policy period)
                action = controller.act(env)
                if controller.status is not None:
                    statuses[controller.status.name] += 1
                    plan_ms.append(1e3 * controller.last.plan_seconds)
                _, _, terminated, truncated, info = env.step(action)
            except RoadFrameError as exc:
                return {**record, "refused": str(exc), "time": clock(sim)}
            speeds.append(float(sim.vehicle.speed))
            collided |= bool(sim.vehicle.crashed)  # lane-keeping-v0 gives no info
            if not (off_road or sim.vehicle.on_road):  # where it first left the road
                off_road = True
                record["off_road_at"] = where(sim)
            reached |= bool(route) and tuple(sim.vehicle.lane_index[:2]) == tuple(route[-2:])
            if collided:
                record["collided_at"] = where(sim)
            if terminated or truncated or collided:
                break
        arrival = reached if given_route else arrived(sim, route, info, reached)  # a given route: its own end
        return {**record, "collided": collided, "off_road": off_road, "arrived": arrival,
                "mean_speed": float(np.mean(speeds)),
                "time": clock(sim), "steps": len(speeds), "statuses": dict(statuses),
                "plan_ms_median": float(np.median(plan_ms)) if plan_ms else None,
                "compile_seconds": controller.compile_seconds, "wall_seconds": time.perf_counter() - start}
    finally:
        env.close()


def where(sim) -> dict:
    """The ego's simulated time [s], position [m] and nearest lane now."""
    vehicle = sim.vehicle
    return {"time": clock(sim), "position": [round(float(x), 2) for x in vehicle.position],
            "lane": [str(part) for part in vehicle.lane_index]}


def frequencies(env_id: str) -> tuple[float, float]:
    """[Hz] (simulation frequency, policy frequency) of ``env_id`` as the table makes it."""
    env = make_env(env_id)
    try:
        return env.unwrapped.config["simulation_frequency"], env.unwrapped.config["policy_frequency"]
    finally:
        env.close()


def holds_several_steps(env_id: str) -> bool:
    """Whether the env holds each action for more than one simulation step (the controller then tracks within it)."""
    simulation_hz, policy_hz = frequencies(env_id)
    return simulation_hz // policy_hz > 1


def plan_rate(env_id: str, hz: float | None) -> float | None:
    """[Hz] how often the controller's optimiser plans within ``env_id``'s policy period when asked to plan ``hz``
    times a second (None: the controller's default, :data:`driveopt.controller.DEFAULT_PLAN_FREQUENCY`); None where
    that is a plan per policy step (not above its policy frequency, or not a divisor of its simulation frequency that
    is a multiple of its policy frequency)."""
    from driveopt.controller import DEFAULT_PLAN_FREQUENCY, replans_at

    rate = DEFAULT_PLAN_FREQUENCY if hz is None else hz
    return rate if replans_at(rate, *frequencies(env_id)) else None


def clock(sim) -> float:
    """[s] simulated time of the episode (lane-keeping-v0's ``step`` leaves upstream's ``time`` at 0)."""
    return sim.steps / sim.config["simulation_frequency"]


def arrived(sim, route, info: dict, reached: bool) -> bool | None:
    """Whether the ego reached the env's destination (see the module docstring; ``reached``: it was on the route's last
    road at a policy step); None without one."""
    if "is_success" in info:  # the env's own success after the last step (exit-v0: in the exit lane or on the exit)
        return bool(info["is_success"])
    if hasattr(sim, "has_arrived"):
        return bool(sim.has_arrived(sim.vehicle))
    return reached if route else None


def summarise(records: list[dict]) -> dict:
    summary: dict = {}
    for r in records:
        row = summary.setdefault(r["env"], {}).setdefault(r["planner"], {
            "episodes": 0, "collisions": 0, "off_road_episodes": 0, "refused": 0, "arrived": None, "speeds": [],
            "plan_ms": []})
        row["episodes"] += 1
        if "refused" in r:
            row["refused"] += 1
            row["refusal"] = r["refused"]
            continue
        row["collisions"] += r["collided"]
        row["off_road_episodes"] += r["off_road"]
        if r.get("arrived") is not None:
            row["arrived"] = (row["arrived"] or 0) + bool(r["arrived"])
        if not r["collided"]:
            row["speeds"].append(r["mean_speed"])
        if r.get("plan_ms_median") is not None:
            row["plan_ms"].append(r["plan_ms_median"])
    for rows in summary.values():
        for row in rows.values():
            speeds, plan_ms = row.pop("speeds"), row.pop("plan_ms")
            row["mean_speed"] = float(np.mean(speeds)) if speeds else None
            row["plan_ms_median"] = float(np.median(plan_ms)) if plan_ms else None
    return summary


def cell(row: dict | None, with_plan_time: bool) -> str:
    """One planner's results on one env as the table shows them: collisions, off road / episodes, refusals, arrivals,
    mean speed [m/s] (episodes without collision), median planning time [ms]."""
    if row is None:
        return "not run"
    if row["refused"] == row["episodes"]:
        return f"refused ({row['refused']} / {row['episodes']})"
    parts = [f"{row['collisions']}, {row['off_road_episodes']} / {row['episodes']}"]
    if row["refused"]:
        parts.append(f"{row['refused']} refused")
    if row["arrived"] is not None:
        parts.append(f"{row['arrived']} arrived")
    parts.append(f"{row['mean_speed']:.2f}" if row["mean_speed"] is not None else "-")
    if with_plan_time and row["plan_ms_median"] is not None:
        parts.append(f"{row['plan_ms_median']:.0f} ms")
    return ", ".join(parts)


def table(results: dict, planners: list[str], samples: int) -> str:
    """The markdown table of docs/controller.md: one row per env, one column per planner."""
    heads = [f"`{p}`, {samples} samples: collisions, off road, arrived, speed [m/s], planning [ms]" if p != "idm"
             else "`idm`: collisions, off road, arrived, speed [m/s]" for p in planners]
    lines = ["| upstream env | " + " | ".join(heads) + " |", "|---" * (len(planners) + 1) + "|"]
    for env_id in sorted(results, key=lambda e: ROWS.index(e) if e in ROWS else len(ROWS)):  # ROWS's order
        rows = results[env_id]
        lines.append(f"| `{env_id}` | " + " | ".join(cell(rows.get(p), p != "idm") for p in planners) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for episodes.jsonl and summary.json")
    parser.add_argument("--envs", nargs="+", default=ROWS, choices=ROWS, help="envs and routed rows (ROUTED_ROWS)")
    parser.add_argument("--planners", nargs="+", default=["bilevel", "idm"])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0, help="episode k is reset with seed + k")
    parser.add_argument("--samples", type=int, default=250)
    parser.add_argument("--duration", type=float, default=20.0, help="[s] at most, per episode")
    parser.add_argument("--config", type=Path, help="planner-config overrides of the optimisers (JSON file)")
    parser.add_argument("--hold-actions", action="store_true",
                        help="hold each action for the policy period instead of tracking the plan within it")
    parser.add_argument("--plan-frequency", type=float, metavar="HZ",
                        help="the optimisers plan HZ times a second where the env's policy frequency is lower "
                             "(default: the controller's, 5 Hz)")
    parser.add_argument("--time-gap", type=float, default=0.0, metavar="S",
                        help="[s] the headway the optimisers' plans keep to the cars in the lanes (Controller's time_gap)")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.samples < 1 or args.duration <= 0:
        parser.error("--episodes, --samples and --duration must be positive")
    if args.plan_frequency is not None and (args.hold_actions or not args.plan_frequency > 0):
        parser.error("--plan-frequency must be > 0 Hz, and tracks plans within the period (not with --hold-actions)")
    from driveopt.scene import EllipseMargin, ProblemError

    try:
        EllipseMargin(time_gap=args.time_gap)
    except ProblemError as exc:
        parser.error(f"--time-gap: {exc}")
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from driveopt.cli import stop_cleanly_on_signals
    from driveopt.experiments.rows_file import row_line
    from driveopt.files import write_json

    stop_cleanly_on_signals()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "episodes.jsonl"
    settings = {"samples": args.samples, "duration": args.duration, "traffic": "upstream's constants"}  # (restored
    # before each episode: earlier records ran with those intersection-v0 leaves for the process, and are driven again)
    config = json.loads(args.config.read_text()) if args.config else None
    if config:  # recorded only when given, so the records of the planners' own configuration stay as they are
        settings["config"] = config
    records = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    records = [r for r in records if r.get("setup") == SETUP.get(r["env"])]  # this setup's (the file keeps all)
    from driveopt.sim.traffic import restore_traffic_constants, traffic_constants

    upstream_traffic = traffic_constants()  # before any env is made (intersection-v0 changes them for the process)
    holds = {env_id: holds_several_steps(env_id) for env_id in ENVS}
    replans = {env_id: plan_rate(env_id, args.plan_frequency) for env_id in ENVS}
    for table_rows in (holds, replans):
        table_rows.update({row: table_rows[env_id] for row, (env_id, _) in ROUTED_ROWS.items()})

    gap = {"time_gap": args.time_gap} if args.time_gap else {}  # recorded only when given, as the config

    from driveopt.errors import DriveoptError
    from driveopt.registry import get_planner

    try:  # each optimiser's configuration, its defaults included: a record planned before a default changed is another run's
        digests = {planner: get_planner(planner).with_samples(args.samples).with_overrides(**(config or {})).config_digest()
                   for planner in {*args.planners, *(r["planner"] for r in records)}}
    except DriveoptError as exc:
        parser.error(str(exc))

    def settings_of(env_id: str, planner: str) -> dict:  # what a record of this run holds: the optimisers' tracking
        tracked = planner != "idm" and not args.hold_actions and holds[env_id]  # (one step a period: nothing to track)
        replanned = {"plan_frequency": replans[env_id]} if tracked and replans[env_id] else {}
        own = {**settings, **gap} if planner != "idm" else settings
        own = {**own, "planner_config": digests[planner]} if digests[planner] else own
        return {**own, "tracked_within_period": True, **replanned} if tracked else own

    def this_runs(record: dict) -> bool:  # a record of these settings (one written before the configuration was
        expected, recorded = settings_of(record["env"], record["planner"]), record.get("settings")  # named: all but it)
        return recorded == expected or (isinstance(recorded, dict) and "planner_config" not in recorded
                                        and recorded == {k: v for k, v in expected.items() if k != "planner_config"})

    done = {(r["env"], r["planner"], r["seed"]) for r in records if this_runs(r)}
    with path.open("a") as out:
        for env_id in args.envs:
            for planner in args.planners:
                for k in range(args.episodes):
                    seed = args.seed + k
                    if (env_id, planner, seed) in done:
                        continue
                    restore_traffic_constants(upstream_traffic)
                    record = {**run_episode(env_id, planner, seed, args.samples, args.duration, config,
                                            not args.hold_actions, None if args.hold_actions else
                                            replans[env_id] or frequencies(env_id)[1],
                                            args.time_gap),
                              "settings": settings_of(env_id, planner)}
                    out.write(row_line(record))
                    out.flush()
                    records.append(record)
                    print(f"{env_id} {planner} seed {seed}: " + ("refused" if "refused" in record else
                          f"collided {record['collided']}, off-road {record['off_road']}, {record['mean_speed']:.1f} m/s"),
                          flush=True)
    chosen = [r for r in records if this_runs(r)]
    summary = {"command": "python benchmarks/studies/upstream_roads.py " + " ".join(argv if argv is not None else os.sys.argv[1:]),
               "settings": {**settings, **gap, "tracked_within_period": not args.hold_actions,
                            **({} if args.hold_actions else {"plan_frequency": args.plan_frequency or "controller's default"})},
               "results": summarise(chosen)}
    write_json(args.out / "summary.json", summary)
    (args.out / "table.md").write_text(table(summary["results"], args.planners, args.samples))
    print(json.dumps(summary["results"], indent=1))
    print(f"wrote {args.out / 'table.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
