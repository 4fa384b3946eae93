"""driveopt's planners driving a CommonRoad scenario, step by step at the scenario's time step.

Execution model ``perfect`` (FISS's benchmark's): at every time step the planner plans from the ego's state, and the
ego is where the followed plan (the plan when SUCCESS, else its fallback stop) is one time step later, read off the
plan's positions, velocities and accelerations (cubic interpolation between its nodes). Obstacles are predicted by
their recording (ground truth, :class:`~driveopt.commonroad.world.Track`), followers included. The goal
(:class:`~driveopt.goal.Goal`) sets the lateral bounds and the desired speed; every verdict is the
:class:`~driveopt.commonroad.evaluate.Evaluator`'s.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from driveopt.commonroad.evaluate import EgoPose, Evaluator
from driveopt.commonroad.world import CommonRoadWorld, Track
from driveopt.scene import EgoState, Neighbour

EXECUTIONS = ("perfect",)
MAX_STEPS = 600  # [-] time steps of a run at most
TAIL_STEPS = 50  # [-] steps after the last recorded obstacle state when the goal has no time window


def max_steps(world: CommonRoadWorld) -> int:
    """Time steps to simulate: to the end of the goal's time window, else 50 past the recording's end."""
    goal = world.problem.goal.state_list[0]
    if goal.has_value("time_step"):
        end = int(getattr(goal.time_step, "end", goal.time_step))
        return max(1, min(MAX_STEPS, end - world.start_step + 1))
    last = max([int(t.steps[-1]) for t in world.tracks if not t.static] or [world.start_step])
    return max(1, min(MAX_STEPS, last - world.start_step + TAIL_STEPS))


def _recorded_futures(problem: Any, present: list[tuple[Neighbour, Track]], ego_x: float, step: int, times: np.ndarray,
                      dt: float) -> Any:
    """``problem`` with each planned-against obstacle's predicted centres replaced by its recording."""
    ox, oy = np.array(problem.obstacle_x, dtype=np.float64), np.array(problem.obstacle_y, dtype=np.float64)
    mask = np.asarray(problem.obstacle_mask)
    for row in np.flatnonzero(mask > 0.5):
        distances = [abs(n.x - (ox[row, 0] + ego_x)) + abs(n.y - oy[row, 0]) for n, _ in present]
        track = present[int(np.argmin(distances))][1]
        s, d = track.future(step, times, dt)
        ox[row], oy[row] = s - ego_x, d
    return problem._replace(obstacle_x=np.asarray(ox, np.float32), obstacle_y=np.asarray(oy, np.float32))


def _after(traj: Any, dt: float) -> tuple[float, float, float, float, float, float]:
    """(x, vx, ax, y, vy, ay) of a trajectory (road frame) at ``dt`` [s]: cubic Hermite positions, linear rates."""
    t = np.asarray(traj.t, dtype=np.float64)
    i = min(int(np.searchsorted(t, dt)) , len(t) - 1)
    i = max(i, 1)
    h = t[i] - t[i - 1]
    u = (dt - t[i - 1]) / h
    out = []
    for p, v, a in ((traj.x, traj.vx, traj.ax), (traj.y, traj.vy, traj.ay)):
        p0, p1, v0, v1 = float(p[i - 1]), float(p[i]), float(v[i - 1]), float(v[i])
        h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
        out += [h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1, v0 + u * (v1 - v0),
                float(a[i - 1]) + u * (float(a[i]) - float(a[i - 1]))]
    return tuple(out)


def pose(world: CommonRoadWorld, step: int, ego: EgoState) -> EgoPose:
    """The ego's world-frame pose from its road-frame state."""
    xy = world.frame.to_world(np.array(ego.x), np.array(ego.y))
    kappa = float(world.frame.curvature(np.array([ego.x]))[0])
    along = (1.0 - kappa * ego.y) * ego.vx  # [m/s] the road-frame rate of s is slower than the speed inside a bend
    speed = math.hypot(along, ego.vy)
    course = math.atan2(ego.vy, along) if speed > 0.05 else (ego.yaw or 0.0)
    accel = (ego.vx * ego.ax + ego.vy * ego.ay) / speed if speed > 0.05 else ego.ax
    return EgoPose(step, float(xy[0]), float(xy[1]), float(world.frame.heading(np.array(ego.x))) + course, speed, accel)


def drive(world: CommonRoadWorld, planner: str = "bilevel", samples: int | None = None, seed: int = 0,
          execution: str = "perfect") -> tuple[dict[str, Any], list[EgoPose]]:
    """Run ``planner`` (a registered optimiser) on ``world``: (record, the executed poses)."""
    import jax

    from driveopt.planner import PlanStatus, PreviousPlan, plan, previous_plan
    from driveopt.problem import build_problem
    from driveopt.registry import get_planner

    if execution not in EXECUTIONS:
        raise ValueError(f"execution must be one of {EXECUTIONS}, got {execution!r}")
    spec = get_planner(planner).with_samples(samples)
    config = spec.config
    times = np.linspace(0.0, config.basis.horizon, config.basis.num_nodes)
    evaluator = Evaluator(world.scenario, world.problem, world.length, world.width)
    ego = world.initial_ego()
    cruise = world.cruise_speed()
    first, _ = world.scene(world.start_step, ego, cruise)
    prior, safety_filter = spec.prior(first.road.num_lanes), spec.safety_filter(first.road.num_lanes)
    key = jax.random.PRNGKey(seed)
    warm = None
    carries = config.cost.consistency > 0
    previous = PreviousPlan.absent(config.basis.num_nodes) if carries else None
    poses = [pose(world, world.start_step, ego)]
    plan_ms, statuses = [], {}
    status, event_step = "timeout", None
    compiled = False
    for i in range(max_steps(world)):
        step = world.start_step + i
        scene, present = world.scene(step, ego, cruise)
        problem = build_problem(scene, config.basis, braking_time=spec.braking_time, selection_time=spec.selection_time,
                                goal=world.goal, time=i * world.dt)
        problem = _recorded_futures(problem, present, ego.x, step, times, world.dt)
        key, sub = jax.random.split(key)
        if not compiled:  # the first call compiles: untimed, its result discarded
            plan(problem, config, key=sub, prior=prior, warm_start=warm, previous=previous, safety_filter=safety_filter,
                 method=spec.method, x_offset=ego.x)
            compiled = True
        start = time.perf_counter()
        result = plan(problem, config, key=sub, prior=prior, warm_start=warm, previous=previous,
                      safety_filter=safety_filter, method=spec.method, x_offset=ego.x)
        plan_ms.append(1000.0 * (time.perf_counter() - start))
        statuses[result.status.name] = statuses.get(result.status.name, 0) + 1
        followed = result.safe_trajectory
        x, vx, ax, y, vy, ay = _after(followed, world.dt)
        if result.status != PlanStatus.SUCCESS:
            vx = max(vx, 0.0)
        ego = EgoState(x=x, y=y, vx=vx, vy=vy, ax=ax, ay=ay, length=world.length, width=world.width)
        warm = result.mean if spec.warm_start else None
        previous = previous_plan(result, world.dt) if carries else None
        poses.append(pose(world, step + 1, ego))
        found = evaluator.event(poses[-1])
        if found is not None:
            status, event_step = ("success" if found == "goal" else found), step + 1
            break
    return _record(world, planner, execution, status, event_step, poses, plan_ms, statuses), poses


def _record(world: CommonRoadWorld, planner: str, execution: str, status: str, event_step: int | None,
            poses: list[EgoPose], plan_ms: list[float], statuses: dict[str, int]) -> dict[str, Any]:
    """The JSONL record of one run (see :mod:`driveopt.commonroad.bench`)."""
    return {
        "scenario": world.name, "planner": planner, "execution": execution, "status": status,
        "success": status == "success", "goal_reached": status == "success",
        "collision": status in ("collision", "collision_while_stopped"),
        "collision_while_stopped": status == "collision_while_stopped", "off_road": status == "off_road",
        "arrival_step": event_step if status == "success" else None, "event_step": event_step,
        "steps": len(poses) - 1, "plans": len(plan_ms),
        "plan_ms_median": float(np.median(plan_ms)) if plan_ms else None,
        "plan_ms_p95": float(np.percentile(plan_ms, 95)) if plan_ms else None,
        "plan_status_counts": statuses,
    }


def record_of(world: CommonRoadWorld, planner: str, execution: str, poses: list[EgoPose], plan_ms: list[float],
              statuses: dict[str, int]) -> dict[str, Any]:
    """The record of a run of another planner's executed ``poses``, judged by the same evaluator."""
    evaluator = Evaluator(world.scenario, world.problem, world.length, world.width)
    status, event_step = evaluator.judge(poses)
    if event_step is not None:
        poses[:] = [p for p in poses if p.step <= event_step]
    return _record(world, planner, execution, status, event_step, poses, plan_ms, statuses)
