"""The last seconds of one bench episode, policy step by policy step: what the car did and what was planned
(``driveopt trace-episode``).

:func:`trace` replays bench episode ``episode`` of ``seed`` (the traffic of ``driveopt bench``: the same
:class:`~driveopt.experiments.store.JobKey` environment seed) with ``planner`` and returns the episode's summary and
one row per policy step: the ego's position [m], speed [m/s] and heading [rad], the action sent, and for an optimiser
the call's status, total residual, chosen set-points (4 speeds [m/s], 4 lateral positions [m]) and the chosen plan's
lateral position at 0.5, 1, 2 and 3 s (where the call found no feasible plan, also the stop executed instead: its
deceleration [m/s^2] and lateral position at those times); then every car within 25 m along and 6 m across as
(dx, dy) [m] relative to the ego and its speed. :func:`step_line` is a row as the command prints it. This is how a
crash of a bench table is read: the approach to the collision, step by step.

Replay on the CPUs the bench episode had: bench binds each local worker to its share of the CPUs (2 workers on 2
CPUs: one each), and a process with another number of CPUs runs XLA's CPU code on another number of threads, which
can round differently; a closed loop amplifies that, and steps later drives another episode. ``taskset -c 1
driveopt trace-episode ...`` replays an episode of a 2-worker bench on 2 CPUs (``vqvae-filter`` at 750 samples,
``p2-four-lane-d3.0`` episode 9: bound, its collision at 17.2 s step for step; unbound, 50 s without one).
"""

from __future__ import annotations

import numpy as np

from driveopt.errors import DriveoptError
from driveopt.experiments.bench import check_options, check_seeds
from driveopt.experiments.rollout import Rollout
from driveopt.experiments.store import JobKey
from driveopt.registry import get_planner
from driveopt.sim import get_scenario

PLAN_TIMES = (0.5, 1.0, 2.0, 3.0)  # [s] after the call: where the chosen plan's lateral position is shown
NEAR = (25.0, 6.0)  # [m] along, across: cars listed around the ego


def step_row(step) -> dict:
    """One policy step: ego state, action, the plan (if any) and the cars nearby."""
    env = step.env.unwrapped
    ego = env.vehicle
    row = {"t": round(float(env.time), 2), "x": round(float(ego.position[0]), 2), "y": round(float(ego.position[1]), 3),
           "speed": round(float(ego.speed), 2), "heading": round(float(ego.heading), 4),
           "action": [round(float(a), 4) for a in np.ravel(step.decision.action)], "guarded": step.decision.guarded}
    result = step.decision.result
    if result is not None:
        plan = result.trajectory
        row.update(status=result.status.name, residual=round(float(result.residuals["total"]), 4),
                   setpoints=[round(float(s), 2) for s in result.setpoints],
                   plan_y=[round(float(np.interp(t, plan.t, plan.y)), 3) for t in PLAN_TIMES])
        if result.status.name != "SUCCESS":  # the stop executed instead: its braking and lateral path
            stop = result.fallback
            row.update(stop_decel=round(float(result.fallback_deceleration), 1),
                       stop_y=[round(float(np.interp(t, stop.t, stop.y)), 3) for t in PLAN_TIMES])
    row["near"] = [[round(float(car.position[0] - ego.position[0]), 1), round(float(car.position[1] - ego.position[1]), 1),
                    round(float(car.speed), 1)]
                   for car in env.road.vehicles
                   if car is not ego and abs(car.position[0] - ego.position[0]) < NEAR[0]
                   and abs(car.position[1] - ego.position[1]) < NEAR[1]]
    return row


def trace(scenario_name: str, planner: str, episode: int, *, seed: int = 42, samples: int | None = 250,
          overrides: dict | None = None, duration: float | None = None,
          weights: str | None = None) -> tuple[dict, list[dict]]:
    """(episode summary, one row per policy step) of the replayed bench episode. ``samples`` and ``overrides`` (planner-
    config overrides, as bench's ``--config``) apply to an optimiser; ``weights``: a learned prior's or policy's
    checkpoint instead of the shipped one (as bench's ``--weights``). DriveoptError (one line) for an unknown scenario
    or planner, unusable weights, a seed and episode whose traffic seed is beyond the simulator's 32 bits, or
    overrides given to a planner without a planner configuration."""
    scenario = get_scenario(scenario_name)
    check_options({"weights": weights})
    check_seeds((seed,), episode + 1)  # its traffic seed, seed x ENV_SEED_STRIDE + episode, must fit in 32 bits
    spec = get_planner(planner).with_weights(weights)
    if spec.is_optimiser:
        spec = spec.with_samples(samples).with_overrides(**(overrides or {}))
    elif overrides:
        raise DriveoptError(f"--config applies to optimisers; {planner} has no planner configuration")
    env_seed = JobKey(scenario_name, planner, seed, episode).env_seed
    rollout = Rollout(scenario, spec.driver(), env_seed, duration=duration)
    rows = [step_row(step) for step in rollout]
    done = rollout.episode
    summary = {"scenario": scenario_name, "planner": planner, "seed": seed, "episode": episode, "env_seed": env_seed,
               "collided": done.collided, "off_road": done.off_road, "end_s": round(done.sim_duration, 2),
               "mean_speed": round(done.mean_speed, 3), "guarded": done.guarded}
    return summary, rows


def step_line(row: dict) -> str:
    """One step's row as a line of text: time, position, speed, heading, the plan (status, residual, set-points, lateral
    positions), the stop executed instead, and the cars nearby."""
    text = f"t={row['t']:5.1f} x={row['x']:7.1f} y={row['y']:+6.2f} v={row['speed']:5.2f} h={row['heading']:+.3f}"
    if "status" in row:
        text += (f" {row['status'][:4]} res={row['residual']:.3f} v_set={row['setpoints'][:4]} y_set={row['setpoints'][4:]}"
                 f" plan_y={row['plan_y']}")
    if "stop_y" in row:
        text += f" stop a={row['stop_decel']:g} y={row['stop_y']}"
    if row["guarded"]:
        text += " GUARDED"
    return text + " | " + " ".join(f"({dx:+.1f},{dy:+.1f}) v{v:.1f}" for dx, dy, v in row["near"])

