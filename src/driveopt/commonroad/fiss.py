"""The FISS planners (``fiss-planner``'s ``fiss_plus``, ``fop`` and the others its benchmark names) on a CommonRoad
scenario, run by FISS's own closed loop (perfect tracking, ground-truth predictions, its goal-speed policy) and judged
by driveopt's :class:`~driveopt.commonroad.evaluate.Evaluator` on the executed states, as driveopt's runs are."""

from __future__ import annotations

from typing import Any

from driveopt.commonroad.drive import record_of
from driveopt.commonroad.evaluate import EgoPose
from driveopt.commonroad.world import VEHICLE, CommonRoadWorld

PLANNERS = ("fiss_plus", "fiss", "fop_plus", "fop")


def drive_fiss(world: CommonRoadWorld, planner: str = "fiss_plus") -> tuple[dict[str, Any], list[EgoPose]]:
    """(record, executed poses) of FISS's ``planner`` on ``world``."""
    from fiss_planner.commonroad.benchmark import Options, run_scenario

    poses: list[EgoPose] = []
    plan_ms: list[float] = []
    statuses: dict[str, int] = {}
    dt, start = world.dt, world.start_step

    def on_step(t: float, ego: Any, obstacles: Any, out: Any, road: Any) -> None:
        step = start + int(round(t / dt))
        poses.append(EgoPose(step, float(ego.x), float(ego.y), float(ego.yaw), float(ego.v), float(ego.a)))
        plan_ms.append(float(out.stats.time_ms))
        mode = "emergency" if out.emergency else "fallback" if out.fallback else "plan"
        statuses[mode] = statuses.get(mode, 0) + 1
        if len(out.trajectory) >= 2:
            nxt = out.trajectory.sample(dt)
            poses.append(EgoPose(step + 1, float(nxt.x), float(nxt.y), float(nxt.yaw), float(nxt.v), float(nxt.a)))

    steps = max(1, min(600, _steps(world)))
    run_scenario(str(world.path), Options(planner=planner, vehicle=VEHICLE, max_steps=steps), on_step=on_step)
    # each step appended (its state, the next): keep one pose per step, the latest written
    by_step = {p.step: p for p in poses}
    ordered = [by_step[k] for k in sorted(by_step)]
    return record_of(world, planner, "perfect", ordered, plan_ms, statuses), ordered


def _steps(world: CommonRoadWorld) -> int:
    from driveopt.commonroad.drive import max_steps

    return max_steps(world)


__all__ = ["PLANNERS", "drive_fiss"]
