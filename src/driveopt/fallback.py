"""Stopping plans: the two stop rows that ride in every sampler batch (unless ``Fallback.in_batch`` is off), and the
fallback, a stop by construction.

The fallback is what a planner offers when no sample is feasible (``PlanResult.fallback``). It is
not a polynomial and it is never projected: it brakes at a constant deceleration along a path
that leads in the ego's direction of travel (:func:`travel_direction`: forwards along the road, or backwards for
a reversing car), so its speed ``max(v0 - d t, 0)`` [m/s] never increases and never goes below zero, and its
velocity never changes sign: a reversing car's stop brakes its backward motion to rest, as a forward stop brakes the
forward motion, and never moves forwards. Both directions are one stop: a lateral profile over the distance
travelled (the path length s), laid out along the road in the direction of travel; so the guarantees of the forward
stop (speed, lateral bounds, no turning back) hold for a reversing one by construction. The path never turns back
(its direction stays within 72 degrees of the road's, forwards or, reversing, backwards). It eases from the current
lateral position and heading to a target inside the road (:func:`lateral_target`): the nearest lane centre
(comfortable stop), the current position clipped to the road (emergency stop) or, with :attr:`Fallback.evasion`, one
of :data:`EVASIONS` (emergency stops that move sideways: to a neighbouring lane line or lane centre, either way), over
20 m or more; with :attr:`Fallback.straightens` it points along the road by the time the car stops (:func:`easing`). Where the ego
starts on the road the path stays between the road bounds; an ego off the road never moves
further away from it. Its residual (how far it is from meeting the constraints) is that of the
polynomial closest to it; when that is not zero the planner still offers the stop and says so
in its status. Of the stops it weighs it offers the one that enters an obstacle's ellipse latest
(:func:`first_contact`; ties, e.g. no contact, by the lower residual): an L2 residual rates a
stop that drives through a slow car ahead in half a second better than one that ends just
inside its ellipse, so ranking by residual alone chose the comfortable stop into a car 24 m
ahead at 20 m/s closing speed. With :attr:`Fallback.evasion` the stops are first ranked by when they would
touch a car (:func:`box_contact`, the box inside the ellipse), then by ellipse entry: the ellipse circumscribes the
box around both cars' corners, so all stops may enter it at once while one of them still passes the car. The
sideways stops are weighed only where both others would touch a car's box: they are for a car whose nearest lane
centre, or whose own position, is in the path of the car it meets (traced in P2's dense traffic: a leader braking
hard or pulling out at the spawn, a car creeping in the lane the fallback eased back into).

The stop rows of the batches (:func:`stop_setpoints`, :func:`braking_coeffs`) are ordinary
candidates: projected and ranked like every sample, so a feasible stop can be the chosen plan.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from driveopt.checks import check_number, check_types
from driveopt.config import MAX_ACCELERATION, PlannerConfig
from driveopt.costs import COST_TERMS, cost_terms, nearest_lane_center
from driveopt.prediction import turned_box_growth
from driveopt.problem import PlanningProblem, ellipse_axes, travel_direction
from driveopt.projection import constraint_residuals
from driveopt.qp import NUM_SEGMENTS, TrajectoryModel, boundary_values, fit_positions
from driveopt.ranking import Candidate, Ranking
from driveopt.scene import CAR_LENGTH, CAR_WIDTH
from driveopt.trajectory import Trajectory

EASING_TIME = 3.0  # [s] the stop rows reach their lateral target in this time
MIN_EASING_DISTANCE = 20.0  # [m] the fallback's lateral change is spread over at least this path length
EASING_DISTANCE_PER_METRE = 6.0  # [m/m] ... and over at least this many metres per metre of lateral change
EASING_CURVATURE = 0.2  # [1/m] ... but over no more than the stopping distance where this curvature allows
MAX_HEADING_SINE = 0.95  # [-] |sin| of the fallback path's heading relative to the road (72 degrees)
_FINE_STEPS = 512  # [-] path samples for integrating x along the path
LANE_CENTRE, HOLD = "centre", "hold"  # lateral targets of a stop (:func:`lateral_target`)
EVASIONS = (-2.0, -1.0, 1.0, 2.0)  # [half-lanes] the sideways targets of ``Fallback.evasion``, from the nearest centre
# (the lane lines and centres on either side: fixed places on the road, so a car that replans its stop every period
# settles on one instead of turning further at every step, as targets relative to its own position let it)


class StopTarget(NamedTuple):
    """A stop's lateral target as numbers, so that stops towards different targets share one traced (vmapped) copy:
    ``hold`` the current lateral position, or else ``offset`` half-lane widths from the nearest lane centre."""

    hold: jnp.ndarray | bool  # [-] the stop keeps its lateral position
    offset: jnp.ndarray | float  # [half-lanes] from the nearest lane centre (0: the centre; +-1 lane lines; +-2 centres)


def stop_target(target: str | float | StopTarget) -> StopTarget:
    """``target`` as a :class:`StopTarget`: ``LANE_CENTRE``, ``HOLD``, a number of half-lane widths from the nearest
    lane centre (a traced one too), or a StopTarget already."""
    if isinstance(target, StopTarget):
        return target
    if isinstance(target, str):
        if target not in (LANE_CENTRE, HOLD):
            raise ValueError(f"unknown stop target {target!r}")
        return StopTarget(target == HOLD, 0.0)
    if not isinstance(target, (int, float, jax.Array)):
        raise ValueError(f"unknown stop target {target!r}")
    return StopTarget(False, target)


def lateral_target(problem: PlanningProblem, y: jnp.ndarray, target: str | float | StopTarget) -> jnp.ndarray:
    """[m] where a stop from lateral position ``y`` [m] eases to: ``LANE_CENTRE`` the nearest lane centre, ``HOLD`` y;
    a number, that many half-lane widths from the nearest lane centre (a lane line at +-1, the next centre at +-2;
    the stop's path clips every target to the road); or a :class:`StopTarget`."""
    hold, offset = stop_target(target)
    return jnp.where(hold, y, nearest_lane_center(problem, y) + offset * 0.5 * problem.lane_width)


def _course(problem: PlanningProblem) -> jnp.ndarray:
    """[-] the car's course as a lateral slope dy/ds (per metre travelled, either direction), within +-0.5."""
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    return jnp.clip(jnp.where(speed > 1e-3, problem.init_y[1] / jnp.maximum(speed, 1e-3), 0.0), -0.5, 0.5)


def stop_setpoints(problem: PlanningProblem, horizon: float, decel: float, target: str | float) -> jnp.ndarray:
    """(8,) set-points describing a stop towards ``target`` (:func:`lateral_target`): longitudinal velocity [m/s] at each
    quarter's end (the speed, negative for a reversing car: :func:`travel_direction`), lateral target [m]."""
    quarter = horizon / NUM_SEGMENTS
    ends = quarter * jnp.arange(1, NUM_SEGMENTS + 1, dtype=jnp.float32)
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    v = travel_direction(problem) * jnp.maximum(speed - decel * ends, 0.0)
    y = lateral_target(problem, problem.init_y[0], target)
    return jnp.concatenate([v, jnp.full(NUM_SEGMENTS, y)])


def braking_coeffs(model: TrajectoryModel, problem: PlanningProblem, decel: float, b_x, b_y,
                   target: str = LANE_CENTRE) -> jnp.ndarray:
    """(2n,) stop at constant deceleration ``decel`` [m/s^2], easing to ``target`` (:func:`lateral_target`) in
    :data:`EASING_TIME`: the batches' stop rows.

    A least-squares fit of that motion (the set-point QP's step set-points would overshoot it), in the direction of
    travel (:func:`travel_direction`).
    """
    t = jnp.asarray(model.t)
    speed = jnp.hypot(problem.init_x[1], problem.init_y[1])
    moving = jnp.minimum(t, speed / decel)
    direction = travel_direction(problem)
    x = problem.init_x[0] + direction * speed * moving - direction * (0.5 * decel) * moving**2
    centre = lateral_target(problem, problem.init_y[0], target)
    tau = jnp.minimum(t / EASING_TIME, 1.0)
    y = problem.init_y[0] + (centre - problem.init_y[0]) * (3 * tau**2 - 2 * tau**3)
    return fit_positions(model, x, y, b_x, b_y)


def easing(slope0: jnp.ndarray, y0: jnp.ndarray, target: jnp.ndarray,
           stop_distance: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(length [m], target [m]) of the fallback's easing from lateral position ``y0`` [m] and slope ``slope0`` [-] to
    the road's direction at lateral position ``target`` [m]: spread over :data:`MIN_EASING_DISTANCE`, or
    :data:`EASING_DISTANCE_PER_METRE` per metre, but done by the time the car stops (``stop_distance`` [m]) where
    :data:`EASING_CURVATURE` allows; when the stop comes sooner than the whole move allows, the move is shortened
    so that the path still points along the road at the stop.

    The start slope is the car's course, which includes the slip of the steering applied now; a path that is still
    turning when the car stops is replanned from that course at every step, so a car braking out of a swerve kept
    its steering and turned on (P2's dense traffic: a corner into a car standing in the next lane).
    """
    k, slope, shift = EASING_CURVATURE, jnp.abs(slope0), target - y0
    gentle = jnp.maximum(MIN_EASING_DISTANCE, EASING_DISTANCE_PER_METRE * jnp.abs(shift))
    # [m] shortest that turns the slope to 0; from 1 m at standstill down to the stop's own distance for a shorter stop
    # (1 cm at least), so that a stop under a metre still ends along the road
    straighten = jnp.maximum(2.0 * slope / k, jnp.clip(stop_distance, 0.01, 1.0))
    length = jnp.minimum(gentle, jnp.maximum(stop_distance, straighten))
    # the cubic Hermite's |y''| peaks at an end: |6 D - 4 L slope0| / L^2 at the start and |6 D - 2 L slope0| / L^2 at
    # the end, for a move D; both <= k bound D to an interval on the course's side, from L slope0 / 3 (the path turns
    # straight without swinging back) to 2 L slope0 / 3 when L is the shortest
    turn, room = length * (3.0 * slope0 + slope), k * length**2
    low, high = (turn - room) / 6.0, (turn - 2.0 * slope * length + room) / 6.0
    return length, jnp.where(length < gentle, y0 + jnp.clip(shift, low, high), target)


def _lateral_path(problem: PlanningProblem, s: jnp.ndarray, target: str | float, stop_distance: jnp.ndarray):
    """(y, dy/ds, d2y/ds2) of the fallback path towards ``target`` (:func:`lateral_target`) at path lengths s [m]
    (arc-length parametrised) for a stop within ``stop_distance`` [m]."""
    y0 = problem.init_y[0]
    slope0 = _course(problem)
    inside = jnp.clip(y0, problem.y_lb, problem.y_ub)
    length, target = easing(slope0, y0, jnp.clip(lateral_target(problem, inside, target), problem.y_lb, problem.y_ub),
                            stop_distance)
    u = jnp.clip(s / length, 0.0, 1.0)
    within = s < length
    # cubic Hermite from (y0, slope0) to (target, 0) over [0, length]; the target beyond
    h00, h10, h01 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2
    y = h00 * y0 + h10 * length * slope0 + h01 * target
    dy = jnp.where(within, ((6 * u**2 - 6 * u) * (y0 - target) + (3 * u**2 - 4 * u + 1) * length * slope0) / length, 0.0)
    d2y = jnp.where(within, ((12 * u - 6) * (y0 - target) + (6 * u - 4) * length * slope0) / length**2, 0.0)
    # never beyond the road bounds (or beyond the start, for an ego outside them): flat where clipped
    low, high = jnp.minimum(y0, problem.y_lb), jnp.maximum(y0, problem.y_ub)
    clipped = (y < low) | (y > high)
    y = jnp.clip(y, low, high)
    dy = jnp.clip(jnp.where(clipped, 0.0, dy), -MAX_HEADING_SINE, MAX_HEADING_SINE)
    d2y = jnp.where(clipped | (jnp.abs(dy) >= MAX_HEADING_SINE), 0.0, d2y)
    return y, dy, d2y


def stop_trajectory(problem: PlanningProblem, t: jnp.ndarray, decel: float, target: str | float,
                    straightens: bool = False) -> Trajectory:
    """The fallback: brake at ``decel`` [m/s^2] from the current speed along the path eased to ``target``
    (:func:`lateral_target`; planning frame), in the direction of travel (:func:`travel_direction`).

    t: (K,) [s] node times. Speed max(v0 - decel t, 0), path length s(t) = its integral. ``straightens``: the easing
    is done by the time the car stops where the curvature allows (:func:`easing`); otherwise it takes its full length.
    The lateral profile is one function of s for both directions; x advances by the path's along-road part times the
    direction, so a reversing stop is the forward stop's path laid out backwards. ``heading`` is the car body's (the
    velocity's direction turned by half a turn when reversing: within 72 degrees of the road either way, as the
    cost's heading term and the box growth of :func:`held_box_growth` read it); ``curvature`` is the path's, signed as
    :func:`driveopt.trajectory.evaluate` signs it.
    """
    speed0 = jnp.hypot(problem.init_x[1], problem.init_y[1])
    direction = travel_direction(problem)
    stop_time = speed0 / decel
    moving = jnp.minimum(t, stop_time)
    s = speed0 * moving - 0.5 * decel * moving**2
    v = jnp.maximum(speed0 - decel * t, 0.0)
    a = jnp.where(t < stop_time, -decel, 0.0)
    # x along the path: integral of sqrt(1 - (dy/ds)^2) ds, on a fine grid up to the stopping distance
    stop_distance = 0.5 * speed0 * stop_time if straightens else jnp.inf
    fine = jnp.linspace(0.0, 1.0, _FINE_STEPS) * jnp.max(s)
    _, dy_fine, _ = _lateral_path(problem, fine, target, stop_distance)
    cos_fine = jnp.sqrt(1.0 - dy_fine**2)
    x_fine = jnp.concatenate([jnp.zeros(1), jnp.cumsum(0.5 * (cos_fine[1:] + cos_fine[:-1]) * jnp.diff(fine))])
    x = problem.init_x[0] + direction * jnp.interp(s, fine, x_fine)
    y, dy, d2y = _lateral_path(problem, s, target, stop_distance)
    dx = jnp.sqrt(1.0 - dy**2)  # along-road part of the path's unit tangent, > 0; times the direction below
    d2x = -dy * d2y / dx
    vx, vy = direction * (v * dx), v * dy
    ax, ay = direction * (a * dx + v**2 * d2x), a * dy + v**2 * d2y
    heading = jnp.arctan2(direction * dy, dx)
    curvature = direction * (dx * d2y - dy * d2x)
    return Trajectory(t, x, y, vx, vy, ax, ay, v, heading, curvature, a)


def _first(inside: jnp.ndarray, problem: PlanningProblem) -> jnp.ndarray:
    """() the first node at which ``inside`` ((N, K): the ego inside obstacle n's region) holds for a real obstacle;
    K when it never does."""
    inside = jnp.any(inside & (problem.obstacle_mask[:, None] > 0), axis=0)  # (K,)
    return jnp.where(jnp.any(inside), jnp.argmax(inside), inside.shape[0])


def first_contact(problem: PlanningProblem, trajectory: Trajectory) -> jnp.ndarray:
    """() index of the first node at which ``trajectory`` (planning frame, (K,) fields) is inside a
    real obstacle's collision ellipse; K when it never is."""
    a, b = ellipse_axes(problem)
    dx = (trajectory.x - problem.obstacle_x) / a
    dy = (trajectory.y - problem.obstacle_y) / b
    return _first(dx * dx + dy * dy < 1.0, problem)


def box_contact(problem: PlanningProblem, trajectory: Trajectory) -> jnp.ndarray:
    """() index of the first node at which ``trajectory``'s centre is inside the box that the collision ellipse
    circumscribes (half-sides a / sqrt 2, b / sqrt 2: the two cars' boxes touch, with the ellipse's margins scaled
    alike), the ellipse grown for the ego's box turned by the largest heading it has had so far (its heading now,
    then the stop's path: :func:`held_box_growth`); K when it never is."""
    growth = jnp.maximum(held_box_growth(problem, trajectory), problem.ellipse_growth)  # (2, K)
    a = problem.obstacle_a[:, None] + growth[0]
    b = problem.obstacle_b[:, None] + growth[1]
    near = (jnp.abs(trajectory.x - problem.obstacle_x) * jnp.sqrt(2.0) < a) & (
        jnp.abs(trajectory.y - problem.obstacle_y) * jnp.sqrt(2.0) < b)
    return _first(near, problem)


def meets_later(problem: PlanningProblem, chosen: Trajectory, fallback: Trajectory, x_offset: float = 0.0) -> bool:
    """Whether ``chosen`` meets the predicted obstacles later than ``fallback`` does, ranked as :meth:`Fallback.choose`
    ranks its stops: by the first touch of a car's box (:func:`box_contact`), then by the first entry into its
    ellipse (:func:`first_contact`); never meeting one is latest. Both in the road frame, whose x is the planning
    frame's plus ``x_offset`` [m]."""
    nodes = problem.obstacle_x.shape[1]

    def meeting(trajectory: Trajectory) -> int:
        trajectory = trajectory._replace(x=jnp.asarray(trajectory.x) - x_offset)
        return int(box_contact(problem, trajectory)) * (nodes + 1) + int(first_contact(problem, trajectory))

    return meeting(chosen) > meeting(fallback)


def held_box_growth(problem: PlanningProblem, trajectory: Trajectory) -> jnp.ndarray:
    """[m] (2, K) growth of the collision ellipses' semi-axes for an ego (the highway-env car) whose box is turned by
    the largest of its heading now and the headings of ``trajectory`` (a stop) up to each node.

    The planner's ellipses grow for the ego's heading now and fade over two seconds because a plan turns the car
    back (:func:`driveopt.prediction.ego_box_growth`); a stop does not: the body heading trails the path's course and
    stays where it is once the car stands. Traced in P2's dense traffic: a sideways stop towards a lane line beside a
    row of standing cars turned the car from 0.12 to 0.24 rad, and its corner met the standing car it stopped
    beside, 0.6 m further across than its centre's box."""
    heading = jnp.maximum(jnp.abs(problem.ego_heading), jax.lax.cummax(jnp.abs(trajectory.heading), axis=0))
    return turned_box_growth(heading, CAR_LENGTH, CAR_WIDTH, xp=jnp)


@dataclass(frozen=True)
class Fallback:
    """The stops a planner weighs as its fallback, and how it chooses one (:meth:`choose`).

    The comfortable stop brakes at ``deceleration`` easing to the nearest lane centre, the emergency stop at the
    projection's ``a_max`` holding the current lateral position; with ``evasion`` the emergency stops towards
    :data:`EVASIONS` are weighed too. With ``in_batch`` (driveopt's default) the comfortable and the emergency stop
    also ride in every sampler batch (:meth:`batch_stops`): projected and ranked like any sample, so a stop that meets
    the constraints can be the chosen plan and the elite set can learn from it; without it (P1) a batch holds the
    samples alone. A frozen dataclass, part of the planner's :class:`driveopt.method.Method`, which
    :func:`driveopt.planner.solve` takes as a static argument.
    """

    deceleration: float = 3.0  # [m/s^2] comfortable braking of the fallback plan
    straightens: bool = True  # the stop points along the road by the time the car stops (:func:`easing`)
    evasion: bool = True  # also weigh emergency stops that move sideways (to the neighbouring lane lines and centres)
    # and rank every stop by its first touch of a car's box before its entry into the car's ellipse (:func:`box_contact`)
    in_batch: bool = True  # the comfortable and the emergency stop ride in every sampler batch (P1: False)

    def __post_init__(self) -> None:
        check_types(self, "fallback")
        check_number("fallback.deceleration", self.deceleration, 0.0, MAX_ACCELERATION, low_open=True, unit="m/s^2")

    def stops(self, a_max: float) -> tuple[tuple[float, str], tuple[float, str]]:
        """(deceleration [m/s^2], lateral target) of the comfortable and of the emergency stop (``a_max`` [m/s^2])."""
        return (self.deceleration, LANE_CENTRE), (a_max, HOLD)

    def batch_stops(self, a_max: float) -> tuple[tuple[float, str], ...]:
        """(deceleration [m/s^2], lateral target) of each stop appended to every sampler batch, in row order: the
        comfortable and the emergency stop (:meth:`stops`) with ``in_batch``, none without."""
        return self.stops(a_max) if self.in_batch else ()

    def braking(self, emergency: bool, a_max: float) -> float:
        """[m/s^2] the deceleration of the chosen stop: ``a_max`` for the emergency stop and its sideways variants."""
        return a_max if emergency else self.deceleration

    def choose(self, model: TrajectoryModel, problem: PlanningProblem, cfg: PlannerConfig,
               ranking: Ranking) -> tuple[Candidate, jnp.ndarray, Trajectory]:
        """(candidate, emergency, trajectory) of the stop offered as fallback: the one that enters an obstacle's
        ellipse latest (with ``evasion``: that touches a car's box latest, then enters its ellipse latest); on a tie
        (none does, or several at once) the one closest to meeting the constraints, the comfortable stop first among
        equals. The sideways stops are weighed only where both standard stops would touch a car's box (a car creeping
        in a jam, inside every ellipse but touching no box, would otherwise be steered sideways by the residual, step
        after step). Residuals and cost terms of all are measured in one batch, on their closest polynomials and their
        own paths; the candidate's key is ``ranking``'s."""
        t = jnp.asarray(model.t)
        standard = self.stops(cfg.projection.a_max)

        def stop(decel, target):  # (path, set-points) of one stop
            return (stop_trajectory(problem, t, decel, target, self.straightens),
                    stop_setpoints(problem, cfg.basis.horizon, decel, target))

        weighed = [*standard, *((cfg.projection.a_max, offset) for offset in EVASIONS if self.evasion)]
        targets = [stop_target(target) for _, target in weighed]
        # every stop in one traced copy (a copy per stop tripled the fallback's share of the planner's compile time)
        every, setpoints = jax.vmap(stop)(jnp.asarray([decel for decel, _ in weighed], dtype=jnp.float32),
                                          StopTarget(jnp.asarray([c.hold for c in targets]),
                                                     jnp.asarray([c.offset for c in targets], dtype=jnp.float32)))
        goal = jnp.stack([every.x[:, -1], every.y[:, -1]], axis=-1) if cfg.qp.terminal_position else None
        b_x, b_y = boundary_values(problem.init_x, problem.init_y, cfg.qp, goal)
        n = every.x.shape[0]
        coeffs = fit_positions(model, every.x, every.y, jnp.broadcast_to(b_x, (n, b_x.shape[-1])),
                               jnp.broadcast_to(b_y, (n, b_y.shape[-1])))
        families = jnp.stack(list(constraint_residuals(model, problem, coeffs, cfg.projection)))  # (4, stops)
        terms = cost_terms(every, problem, time_constant=cfg.cost.time_constant)
        cost = ranking.driving_cost(every, problem, terms, cfg.cost)
        total = jnp.sum(families, axis=0)
        feasible = total <= cfg.sampler.residual_tolerance
        key = ranking.key(ranking.score(cost, total), total, feasible)
        contact = jax.vmap(lambda path: first_contact(problem, path))(every)
        if self.evasion:  # the box first, the ellipse on a tie; sideways stops only where both others touch a box
            nodes = model.t.shape[0]
            box = jax.vmap(lambda path: box_contact(problem, path))(every)
            sideways_weighed = jnp.all(box[:len(standard)] < nodes)
            contact = jnp.where((jnp.arange(n) < len(standard)) | sideways_weighed, contact + (nodes + 1) * box, -1)
        latest = contact == jnp.max(contact)
        pick = jnp.argmin(jnp.where(latest, total, jnp.inf))  # the first of equals
        term_values = jnp.stack([terms[k] for k in COST_TERMS])  # (terms, stops)
        candidate = Candidate(key[pick], feasible[pick], setpoints[pick], coeffs[pick], families[:, pick],
                              term_values[:, pick], cost[pick])
        return candidate, pick > 0, jax.tree_util.tree_map(lambda a: a[pick], every)
