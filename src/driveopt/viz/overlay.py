"""A driver's plans over the env's own rendered frame, in world coordinates on any road, with a heads-up display.

    frame = render_decision(env, decision, planner="bilevel", v_des=20.0, config=driver.config)

``env`` is a highway-env env made with ``render_mode="rgb_array"``; its frame follows the ego (upstream's
viewer centres it at ``centering_position`` of the screen) and has the env's ``screen_width`` x
``screen_height`` [px] at ``scaling`` [px/m]. On it go the last sampler iteration's samples and elites
and the plan the car follows, each turned from the road frame the plan was made in into world points
(:func:`driveopt.viz.video.plan_overlay_arrays`: straight, circular and sine lanes), the neighbours' predicted
boxes at :data:`PREDICTION_TIMES` (faint outlines: where the planner expected them), and a box in the
top-left corner with the simulated time [s], the ego's speed and the desired speed [m/s] with where it comes from, the planner,
the planning status (``fallback`` when the car brakes on the fallback, ``guarded`` when the contact
guard braked) and the planning call's wall time [ms]. :meth:`driveopt.Controller.render` is this for the
controller's latest plan; ``driveopt drive --video`` writes these frames.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from driveopt.config import PlannerConfig
from driveopt.errors import DriveoptError
from driveopt.viz.video import draw_plan, plan_overlay_arrays

MAX_SAMPLES = 40  # [-] sampled plans drawn per frame (each is turned into world points: ~1 ms on a curved road)
PREDICTION_TIMES = (1.0, 2.0, 3.0)  # [s] horizon times at which the neighbours' predicted boxes are drawn
CAR_LENGTH, CAR_WIDTH = 5.0, 2.0  # [m] the drawn predicted boxes (highway-env's car)


class RenderError(DriveoptError):
    """The env cannot be rendered with the plan (no ``rgb_array`` render mode, not a highway-env env)."""


class Hud(NamedTuple):
    """What the heads-up display shows."""

    time: float  # [s] simulated since the env's reset
    speed: float  # [m/s] the ego's speed
    v_des: float | None  # [m/s] desired speed the plan was made for (None: unknown)
    planner: str
    status: str  # the planning status's name, "fallback", "guarded", or "-" (no plan yet, or a driver that plans none)
    plan_ms: float | None  # [ms] wall time of the planning call (None: none)
    v_des_source: str | None = None  # where the desired speed comes from ("lane limit", "curve ahead, ...", ...)

    def lines(self) -> list[str]:
        desired = "-" if self.v_des is None else f"{self.v_des:.1f}"
        if self.v_des is not None and self.v_des_source:
            desired += f" from {self.v_des_source}"
        plan = "-" if self.plan_ms is None else f"{self.plan_ms:.0f} ms"
        return [f"t {self.time:5.1f} s   v {self.speed:4.1f} m/s (desired {desired})",
                f"{self.planner}: {self.status}   plan {plan}"]


def follows_fallback(decision: Any) -> bool:
    """Whether the car follows the decision's fallback (braking), not its chosen plan: a plan that is not SUCCESS,
    unless the followed plan (``plan_world``) ends where the chosen one does (P1 executes infeasible plans)."""
    result = decision.result
    if result.status.name == "SUCCESS":
        return False
    world, frame = decision.plan_world, decision.frame
    if world is None or frame is None:
        return True
    x, y = frame.to_world(np.asarray(result.trajectory.x)[-1:], np.asarray(result.trajectory.y)[-1:])[:2]
    return not (np.allclose(x, np.asarray(world.x)[-1:]) and np.allclose(y, np.asarray(world.y)[-1:]))


def status_text(decision: Any) -> str:
    """The HUD's status of a :class:`~driveopt.drivers.base.Decision` (None: no decision yet)."""
    if decision is None or decision.result is None:
        return "guarded" if decision is not None and decision.guarded else "-"
    name = decision.result.status.name
    if decision.guarded:
        return f"{name}, guarded"
    return f"{name}, fallback" if follows_fallback(decision) else name


CURVE_SLOWDOWN = 0.05  # [m/s] a planned desired speed this far below the task's was lowered for a curve ahead


def hud_of(env: Any, decision: Any, planner: str, v_des: float | None, v_des_source: str | None = None) -> Hud:
    """The HUD of ``env``'s current state and the ``decision`` (or None) that ``planner`` made; ``v_des`` [m/s] and
    ``v_des_source`` (e.g. ``"lane limit"``): the task's desired speed and where it comes from. When the decision's
    scene planned for less (a curve ahead, :func:`driveopt.sim.perception.curve_speed`), the HUD shows that speed
    and says so: a rate along the road's reference line, which beside the line on a curve is not the car's own
    speed (on the outside of a curve it reads lower than the car will drive)."""
    sim = env.unwrapped
    time = sim.steps / sim.config["simulation_frequency"]
    plan_ms = 1e3 * decision.plan_seconds if decision is not None and decision.result is not None else None
    scene = getattr(decision, "scene", None)
    if v_des is not None and scene is not None and float(scene.v_des) < v_des - CURVE_SLOWDOWN:
        v_des_source = f"curve ahead ({v_des_source}: {v_des:.1f})" if v_des_source else "curve ahead"
        v_des = float(scene.v_des)
    return Hud(float(time), float(sim.vehicle.speed), v_des, planner, status_text(decision), plan_ms, v_des_source)


def decision_overlay(decision: Any, config: PlannerConfig | None, max_samples: int = MAX_SAMPLES) -> dict[str, Any]:
    """``draw_plan`` keywords (samples, elites, chosen: world xy [m]; fallback) of a decision's plan; empty without
    one. The chosen line is the plan the car follows (``decision.plan_world``) when the driver gives it."""
    result = None if decision is None else decision.result
    if result is None or decision.frame is None:
        return {}
    samples = elites = None
    if config is not None and getattr(result, "last", None) is not None:
        samples, elites, chosen = plan_overlay_arrays(result, config, max_samples, road_frame=decision.frame)
    world = decision.plan_world
    if world is not None:
        chosen = np.stack([np.asarray(world.x), np.asarray(world.y)], axis=-1)
    elif samples is None:
        return {}
    return {"samples": samples, "elites": elites, "chosen": chosen, "fallback": follows_fallback(decision),
            "predicted": predicted_boxes(decision, config)}


def predicted_boxes(decision: Any, config: PlannerConfig | None, times: tuple[float, ...] = PREDICTION_TIMES
                    ) -> np.ndarray | None:
    """(M, 4, 2) world corners [m] of the boxes (:data:`CAR_LENGTH` x :data:`CAR_WIDTH`) of every neighbour the
    decision planned against, where its problem predicted it at each of ``times`` [s] (the nearest time node),
    oriented along the predicted motion; None without a problem, a frame or a config (the node times come from its
    basis)."""
    problem, frame, result = getattr(decision, "problem", None), getattr(decision, "frame", None), decision.result
    if problem is None or frame is None or config is None or result is None:
        return None
    x, y = np.asarray(problem.obstacle_x, float), np.asarray(problem.obstacle_y, float)
    real = np.flatnonzero(np.asarray(problem.obstacle_mask) > 0)
    nodes = x.shape[1]
    if real.size == 0 or nodes < 2:
        return np.zeros((0, 4, 2))
    step = config.basis.horizon / (nodes - 1)  # [s] between time nodes
    picked = sorted({min(int(round(t / step)), nodes - 2) for t in times})
    rows, cols = np.repeat(real, len(picked)), np.tile(picked, real.size)
    s, d = x[rows, cols] + float(result.x_offset), y[rows, cols]
    ds, dd = x[rows, cols + 1] - x[rows, cols], y[rows, cols + 1] - y[rows, cols]
    along = np.where(np.hypot(ds, dd) > 1e-6, np.arctan2(dd, ds), 0.0)  # [rad] to the reference line (0: standing)
    cx, cy, reference = frame.to_world(s, d)[:3]
    heading = np.asarray(reference) + along
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [CAR_LENGTH / 2.0, CAR_WIDTH / 2.0]  # (4, 2) car frame
    cos, sin = np.cos(heading)[:, None], np.sin(heading)[:, None]
    corners_x = np.asarray(cx)[:, None] + cos * half[:, 0] - sin * half[:, 1]
    corners_y = np.asarray(cy)[:, None] + sin * half[:, 0] + cos * half[:, 1]
    return np.stack([corners_x, corners_y], axis=-1)


def render_decision(env: Any, decision: Any, *, planner: str, v_des: float | None, config: PlannerConfig | None = None,
                    frame: np.ndarray | None = None, max_samples: int = MAX_SAMPLES, v_des_source: str | None = None
                    ) -> np.ndarray:
    """(H, W, 3) uint8: ``frame`` (default ``env.render()``) with ``decision``'s plans in world coordinates and the HUD.

    ``config``: the planner config the plan was made with (its basis turns the batch's coefficients into points;
    None draws only the followed plan); ``v_des_source``: where ``v_des`` comes from, for the HUD. RenderError when
    the env does not render RGB frames."""
    if frame is None:
        frame = rgb_frame(env)
    hud = hud_of(env, decision, planner, v_des, v_des_source)
    return draw_plan(frame, env, hud=hud.lines(), **decision_overlay(decision, config, max_samples))


def rgb_frame(env: Any) -> np.ndarray:
    """``env.render()``, checked to be an RGB frame; RenderError naming what to change otherwise."""
    mode = getattr(env, "render_mode", None)
    if mode != "rgb_array":
        raise RenderError(f"the env renders with render_mode={mode!r}: make it with render_mode='rgb_array' "
                          "(gymnasium.make(..., render_mode='rgb_array')) to draw plans on its frames")
    frame = env.render()
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[2] != 3:
        raise RenderError(f"env.render() returned {type(frame).__name__}, not an (H, W, 3) RGB frame")
    return frame
