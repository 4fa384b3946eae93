"""driveopt's planners driving a CommonRoad scenario, step by step at the scenario's time step.

At every time step the planner plans from the ego's state; the execution model moves the ego to its next state:
``perfect`` (FISS's benchmark's): the ego is where the followed plan (the plan when SUCCESS, else its fallback stop) is
one time step later, read off the plan's positions, velocities and accelerations (cubic interpolation between its
nodes); ``tracked``: driveopt's kinematic bicycle follows the followed plan with driveopt's tracker over the step
(:mod:`~driveopt.commonroad.execution`). Obstacles are predicted by
their recording (ground truth, :class:`~driveopt.commonroad.world.Track`), followers included, each inside the
segment ellipses of :mod:`~driveopt.commonroad.cover` while rows are free (:func:`obstacle_rows`). The goal
(:class:`~driveopt.goal.Goal`) sets the lateral bounds and the desired speed, and the previous plan's lateral
set-points are held inside the bounds (:func:`previous_within_bounds`); every verdict is the
:class:`~driveopt.commonroad.evaluate.Evaluator`'s.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from driveopt.commonroad import EXECUTIONS
from driveopt.commonroad import execution as tracked
from driveopt.commonroad.cover import box_cover, cover_pieces
from driveopt.commonroad.evaluate import EgoPose, Evaluator
from driveopt.commonroad.world import CommonRoadWorld, Track
from driveopt.prediction import relevant_neighbours
from driveopt.qp import NUM_SEGMENTS
from driveopt.scene import EgoState, Neighbour, Scene

MAX_STEPS = 600  # [-] time steps of a run at most
TAIL_STEPS = 50  # [-] steps after the last recorded obstacle state when the goal has no time window
MAX_ROWS = 10  # [-] obstacle rows a plan is compiled for at most (build_problem's default)


def max_steps(world: CommonRoadWorld) -> int:
    """Time steps to simulate: to the end of the goal's time window, else 50 past the recording's end."""
    goal = world.problem.goal.state_list[0]
    if goal.has_value("time_step"):
        end = int(getattr(goal.time_step, "end", goal.time_step))
        return max(1, min(MAX_STEPS, end - world.start_step + 1))
    last = max([int(t.steps[-1]) for t in world.tracks if not t.static] or [world.start_step])
    return max(1, min(MAX_STEPS, last - world.start_step + TAIL_STEPS))


def row_count(world: CommonRoadWorld, steps: int) -> int:
    """[-] obstacle rows for a run of ``steps`` time steps: the most obstacles present at one step, each in its
    :func:`~driveopt.commonroad.cover.cover_pieces` segments, at most :data:`MAX_ROWS`, at least 1. The projection's
    work grows with the rows, padding or not (about 10 % from 4 to 10 rows)."""
    most = max(sum(track.index(world.start_step + i) is not None for track in world.tracks) for i in range(steps + 1))
    return max(1, min(MAX_ROWS, most * cover_pieces()))


def obstacle_rows(problem: Any, scene: Scene, present: list[tuple[Neighbour, Track]], step: int, times: np.ndarray,
                  dt: float, selection_time: float, braking_time: float) -> Any:
    """``problem`` with each planned-against obstacle's predicted centres replaced by its recording, and each one's
    collision ellipse replaced, while padding rows are left, by the tighter cover of
    :func:`~driveopt.commonroad.cover.box_cover` (one row per segment, most relevant obstacle first).

    The rows are matched to the obstacles by :func:`~driveopt.prediction.relevant_neighbours` with ``build_problem``'s
    arguments (``selection_time``, ``braking_time`` [s]): its rows in its order (matched by position, a car merging
    from off the road, whose predicted lateral position ``build_problem`` clips onto the road, was taken for another
    car and planned against twice, itself not at all)."""
    ego = scene.ego
    rows = int(np.shape(problem.obstacle_x)[0])
    chosen = relevant_neighbours(scene, rows, False, selection_time, braking_time)
    tracks = {id(n): track for n, track in present}
    ox, oy = np.array(problem.obstacle_x, dtype=np.float64), np.array(problem.obstacle_y, dtype=np.float64)
    oa, ob = np.array(problem.obstacle_a, dtype=np.float64), np.array(problem.obstacle_b, dtype=np.float64)
    mask = np.array(problem.obstacle_mask, dtype=np.float64)
    if int(np.sum(mask > 0.5)) != len(chosen):
        raise RuntimeError(f"{len(chosen)} obstacles chosen but {int(np.sum(mask > 0.5))} rows planned against")
    free = len(chosen)  # the first padding row
    for row, n in enumerate(chosen):
        s, d = tracks[id(n)].future(step, times, dt)
        ox[row], oy[row] = s - ego.x, d
        other_long, other_lat = n.half_extents
        centres, a, b = box_cover(0.5 * ego.length + other_long, 0.5 * ego.width + other_lat)
        if free + len(centres) - 1 > rows:
            continue  # no room: the single ellipse stays
        margin, centre_x, centre_y = scene.ellipse_margin, ox[row].copy(), oy[row].copy()
        for target, offset in zip([row] + list(range(free, free + len(centres) - 1)), centres):
            ox[target], oy[target] = centre_x + offset, centre_y
            oa[target], ob[target], mask[target] = a + margin.longitudinal, b + margin.lateral, 1.0
        free += len(centres) - 1
    f32 = lambda v: np.asarray(v, np.float32)  # noqa: E731
    return problem._replace(obstacle_x=f32(ox), obstacle_y=f32(oy), obstacle_a=f32(oa), obstacle_b=f32(ob),
                            obstacle_mask=f32(mask))


def previous_within_bounds(previous: Any, problem: Any) -> Any:
    """``previous`` (a :class:`~driveopt.planner.PreviousPlan`) with its lateral set-points [m] clipped into
    ``problem``'s lateral bounds, as the sampler clips its own.

    The previous plan's set-points are re-solved as a candidate at every replan. Set-points from before a goal's band
    was imposed lie outside it; the projection's off-road recovery lets that plan enter the band only by
    ``recovery_time`` (3 s), so it stayed feasible and, cheapest against itself (``consistency``), was chosen at every
    replan: each replan put the return off by another step, and the car never reached the band."""
    setpoints = np.array(previous.setpoints, dtype=np.float32)
    setpoints[NUM_SEGMENTS:] = np.clip(setpoints[NUM_SEGMENTS:], float(problem.y_lb), float(problem.y_ub))
    return previous._replace(setpoints=setpoints)


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
    car = model = None
    if execution == "tracked":
        from commonroad_dc.feasibility.vehicle_dynamics import VehicleParameterMapping

        from driveopt.commonroad.world import VEHICLE

        model = tracked.vehicle_model(VehicleParameterMapping[VEHICLE].value, world.dt)
        car = tracked.initial_car(world.problem.initial_state)
        ego = tracked.frame_state(car, world.frame, model, world.length, world.width)
    cruise = world.cruise_speed()
    first, _ = world.scene(world.start_step, ego, cruise)
    prior, safety_filter = spec.prior(first.road.num_lanes), spec.safety_filter(first.road.num_lanes)
    key = jax.random.PRNGKey(seed)
    warm = None
    carries = config.cost.consistency > 0
    previous = PreviousPlan.absent(config.basis.num_nodes) if carries else None
    poses = [pose(world, world.start_step, ego) if car is None else tracked.car_pose(world.start_step, car)]
    plan_ms, statuses, deviations = [], {}, []
    status, event_step = "timeout", None
    compiled = False
    steps = max_steps(world)
    rows = row_count(world, steps)
    for i in range(steps):
        step = world.start_step + i
        scene, present = world.scene(step, ego, cruise)
        problem = build_problem(scene, config.basis, rows, braking_time=spec.braking_time, selection_time=spec.selection_time,
                                goal=world.goal, time=i * world.dt)
        problem = obstacle_rows(problem, scene, present, step, times, world.dt, spec.selection_time, spec.braking_time)
        key, sub = jax.random.split(key)
        if previous is not None:
            previous = previous_within_bounds(previous, problem)
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
        if car is None:  # perfect
            x, vx, ax, y, vy, ay = _after(followed, world.dt)
            if result.status != PlanStatus.SUCCESS:
                vx = max(vx, 0.0)
            ego = EgoState(x=x, y=y, vx=vx, vy=vy, ax=ax, ay=ay, length=world.length, width=world.width)
            poses.append(pose(world, step + 1, ego))
        else:  # tracked
            brake = None if result.status == PlanStatus.SUCCESS else float(result.fallback_deceleration)
            car, deviation = tracked.step(car, followed, world.frame, model, brake)
            deviations.append(deviation)
            ego = tracked.frame_state(car, world.frame, model, world.length, world.width)
            poses.append(tracked.car_pose(step + 1, car))
        warm = result.mean if spec.warm_start else None
        previous = previous_plan(result, world.dt) if carries else None
        found = evaluator.event(poses[-1])
        if found is not None:
            status, event_step = ("success" if found == "goal" else found), step + 1
            break
    record = _record(world, planner, execution, status, event_step, poses, plan_ms, statuses)
    if deviations:  # tracked: how far the car ended each step from where the followed plan was then
        record["tracking_m_median"] = float(np.median(deviations))
        record["tracking_m_max"] = float(np.max(deviations))
    return record, poses


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
