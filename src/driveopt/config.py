"""Static configuration of the planner: frozen, hashable dataclasses.

Every field carries its unit. Instances are used as static arguments of the
jit-compiled planning function, so two equal configs share one compilation.
Defaults follow P1 (bi-level planner) unless a comment says otherwise.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from driveopt.checks import ConfigError, check_budget, check_count, check_types, require

MIN_HORIZON = 1.0  # [s] shortest planning horizon (each of the four set-point quarters lasts T / 4); far below it
# (1e-30 s) the basis's derivatives (1/T, 1/T^2) leave float32's range and every plan is NaN
MAX_HORIZON = 120.0  # [s] longest planning horizon
MAX_SPEED = 100.0  # [m/s] highest speed bound
MAX_ACCELERATION = 100.0  # [m/s^2] highest acceleration bound
MAX_WEIGHT = 1e6  # [-] highest cost weight, gain or penalty weight
MIN_TEMPERATURE = 1e-6  # [-] lowest sampler temperature: far below it (1e-300) it rounds to 0 in float32 and the
# elite weights exp(-(c - min c) / temperature) are 0 / 0 = NaN
DERIVATIVE_BOUNDS = ("nodes", "control_points")  # values of ProjectionConfig.derivative_bounds
NEAREST_CHOICES = ("sample", "batch")  # values of ProjectionConfig.nearest_choice


@dataclass(frozen=True)
class BasisConfig:
    """Bernstein polynomial trajectory basis."""

    order: int = 10  # Bernstein polynomial order (order + 1 coefficients per axis)
    horizon: float = 15.0  # [s] planning horizon T, in [1, 120]
    num_nodes: int = 100  # time nodes on [0, T], both ends included (divisible by 4: one segment per set-point)

    def __post_init__(self) -> None:
        check_types(self, "basis")
        require(3 <= self.order <= 20, f"basis.order must be in [3, 20], got {self.order}")
        require(MIN_HORIZON <= self.horizon <= MAX_HORIZON,
                f"basis.horizon must be in [{MIN_HORIZON:g}, {MAX_HORIZON:g}] s, got {self.horizon:g}")
        require(8 <= self.num_nodes <= 2000, f"basis.num_nodes must be in [8, 2000], got {self.num_nodes}")
        require(self.num_nodes % 4 == 0, "basis.num_nodes must be divisible by 4 (one segment per set-point)")

    @property
    def num_coeffs(self) -> int:
        return self.order + 1

    @property
    def dt(self) -> float:
        """[s] spacing of the time nodes."""
        return self.horizon / (self.num_nodes - 1)


@dataclass(frozen=True)
class QPConfig:
    """Set-point QP (DESIGN §2.2): smoothness + PD set-point tracking."""

    w_smooth: float = 0.1  # [-] weight of ||x''||^2 + ||y''||^2 in the set-point QP
    w_speed: float = 1.0  # [-] weight of the speed-tracking residual
    w_lateral: float = 1.0  # [-] weight of the lateral-tracking residual
    k_pv: float = 20.0  # [1/s] P gain of speed tracking
    k_p: float = 20.0  # [1/s^2] P gain of lateral tracking
    k_d: float = 2.0 * math.sqrt(20.0)  # [1/s] D gain of lateral tracking
    initial_acceleration: bool = True  # impose x''(0), y''(0); False when acceleration is a control input that can jump
    initial_lateral_acceleration: bool = False  # with initial_acceleration, also impose y''(0) (P1: true); the steering can jump
    terminal_position: bool = False  # also impose x(T) = x_f, y(T) = y_f (the goal-sampling baseline ``batch``)
    terminal_longitudinal: bool = True  # with terminal_position, impose x(T) = x_f too; False: only y(T) = y_f, the
    # speed tracked as a set-point (the authors' Batch-MPC, ``batch-faithful``: expert_batch.py's A_eq_x has no x(T) row)

    def __post_init__(self) -> None:
        check_types(self, "qp")
        for name in ("w_smooth", "w_speed", "w_lateral", "k_pv", "k_p", "k_d"):
            value = getattr(self, name)
            require(0 <= value <= MAX_WEIGHT, f"qp.{name} must be in [0, {MAX_WEIGHT:g}], got {value:g}")
        require(self.w_smooth > 0, "qp.w_smooth must be > 0 (it keeps the QP strictly convex)")
        require(self.terminal_position or self.terminal_longitudinal,
                "qp.terminal_longitudinal = false needs qp.terminal_position = true (it only leaves out x(T) = x_f)")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "QPConfig":
        """The QP section recorded in a checkpoint's header. Checkpoints of the learned priors record every field of
        the QP inside their decoder; two terms the QP no longer has are accepted while they are off (as in every
        shipped checkpoint) and refused when on, since that decoder solved another QP."""
        data = dict(data)
        for name, off in _DROPPED_QP_TERMS.items():
            if name in data and data.pop(name) != off:
                raise ConfigError(f"qp.{name} is on in this checkpoint's QP; driveopt's set-point QP has no such term")
        return cls(**data)


_DROPPED_QP_TERMS = {"initial_acceleration_weight": 0.0, "terminal_lateral_acceleration": False}  # name -> "off"


@dataclass(frozen=True)
class ProjectionConfig:
    """Batch projection onto the constraint set (DESIGN §2.3)."""

    max_iterations: int = 20  # [-] alternating-minimisation iterations; 0: no projection, every sample is ranked as drawn
    # (P2 Fig. 9's "no filter" ablation); the registered ``bilevel`` runs 12 with ``anderson_window`` 4,
    # ``derivative_bounds`` "control_points" and ``early_iterations`` 7 (``driveopt.registry.REALTIME_PROJECTION``;
    # docs/results/speed.md)
    early_iterations: int = 0  # [-] > 0: every sampler iteration but the last projects with this many iterations (at
    # most ``max_iterations``: a larger count changes nothing) and only the last with ``max_iterations`` (the earlier
    # batches mainly steer the sampling distribution, their best rows still compete for the pick;
    # docs/results/speed.md); 0: ``max_iterations`` in every sampler iteration
    tolerance: float = 1e-3  # [m] early stop when no coefficient of any sample moved more than this in the last iteration
    rho_obstacle: float = 1.0  # [-] penalty weight of the obstacle rows
    rho_velocity: float = 10.0  # [-] penalty weight of the velocity rows
    rho_acceleration: float = 10.0  # [-] penalty weight of the acceleration rows
    rho_lane: float = 1.0  # [-] penalty weight of the lane rows
    v_min: float = 0.0  # [m/s] speed lower bound (P1: 0.1; 0 lets a plan stop, as the fallback does)
    v_max: float = 30.0  # [m/s] speed upper bound
    a_max: float = 18.0  # [m/s^2] acceleration-magnitude bound (the closed loop caps it at what the car can do)
    kappa_max: float = 0.23  # [1/m] path-curvature bound, not applied below 1 m/s (0 disables it)
    centripetal_max: float = 7.0  # [m/s^2] bound on the lateral acceleration the road's curvature k gives the car,
    # x'^2 |k| (1 - k (y - y0)) at y beside the line y0 it is the curvature of: a curve's speed (upstream's IDM turns
    # at up to 6.67 on its racetrack; at 6 roundabout-v0's exit was reached in 13 of 20 episodes within its 11 s, at 7
    # in 17: docs/controller.md)
    barrier: bool = False  # P2's discrete-time barrier forms for obstacles and lanes
    gamma_obs: float = 1.0  # [-] in (0, 1]: obstacle barrier parameter with ``barrier`` (1: the plain bound d >= 1; P2 trains
    # with 0.98); a safety filter's per-sample values replace it
    gamma_lane: float = 1.0  # [-] in (0, 1]: lane barrier parameter with ``barrier`` (1: the plain bound; P2: 0.9); likewise
    recovery_time: float = 3.0  # [s] a car off the lane bounds (or drifting past them), or whose course exceeds
    # ``course_max``, must be back within them by then (0: never relaxed)
    acceleration_recovery: bool = False  # the acceleration bound, too, starts at the car's acceleration where that is
    # above it and narrows to ``a_max`` by ``recovery_time``: after braking at the car's limit on a bend every plan starts
    # above the bound (docs/controller.md); on in the registered ``bilevel`` (``driveopt.registry.REALTIME_PROJECTION``)
    course_max: float = 0.35  # [rad] bound on the angle between the velocity and the direction of travel along the road (0: no
    # bound, P1)
    course_min_speed: float = 1.0  # [m/s] the course bound applies where the speed exceeds this (below it a stopping
    # car's direction means little: a car that crawls sideways is held only to a right angle, never backwards)
    ego_turn_rate: float = 0.179  # [rad/m] > 0: the lateral growth of the ellipses for the ego's turned box lasts, per
    # sample, until its heading has fallen this much per metre the sample travels along the road (a plan that stands keeps
    # it), and at least over the plan's first seconds (problem.ellipse_growth; 0: only those); 0.179 is
    # highway-env's bicycle at full lock
    anderson_window: int = 0  # [-] Anderson acceleration of the alternating minimisation (docs/results/speed.md): each step mixes
    # the last this many iterates of a sample (3 to 5), kept only where it lowers that sample's fixed-point residual; 0: off
    relaxation: float = 1.0  # [-] in (0, 2): each step moves the multipliers and pulls this multiple of the way to the
    # next iterate (below 1 damped, above 1 over-relaxed); 1: off
    derivative_bounds: str = "nodes"  # where the projection's velocity [m/s] and acceleration [m/s^2] rows act: "nodes" (at
    # every time node; the default) or "control_points" (docs/results/speed.md: at the Bernstein control points of each on
    # ``derivative_pieces`` equal pieces of the horizon: fewer rows, and a bound on the speed or acceleration magnitude
    # met there holds at every time; the rows' other bounds, course, centripetal, curvature and lower speed, are applied
    # there too, as approximations). Residuals are measured at the nodes either way
    derivative_pieces: int = 4  # [-] in [1, 16], with "control_points": the pieces, each with basis.order control points
    # (the shared ones once); more pieces bring the points closer to the curve, so the bounds are less conservative
    nearest_obstacles: int = 0  # [-] 0: every obstacle has rows at every node (the default); k > 0: at each node only
    # the k obstacles nearest (by ellipse ratio) the target trajectories, chosen once per projection
    # (docs/results/speed.md): k rows per node instead of one per obstacle. Residuals count every obstacle
    nearest_choice: str = "sample"  # with nearest_obstacles: "sample" (each sample its own k nearest at each node) or
    # "batch" (the k obstacles that come nearest to any sample at each node, one choice for the whole batch: the rows
    # read each obstacle's per-node values as the plain rows do, with no per-sample copies)
    obstacle_stride: int = 1  # [-] in [1, 16]: beyond ``obstacle_dense_time`` only every this-many-th node (and the last)
    # carries obstacle rows, each ellipse grown by the ego's motion relative to the obstacle over the nodes left out
    # (docs/results/speed.md); 1: every node (the default). Residuals count every node
    obstacle_dense_time: float = 3.0  # [s] with ``obstacle_stride`` > 1, every node up to this time carries obstacle rows

    @property
    def earlier_iterations(self) -> int:
        """[-] the projection iterations of every sampler iteration but the last."""
        return min(self.early_iterations, self.max_iterations) if self.early_iterations else self.max_iterations

    def __post_init__(self) -> None:
        check_types(self, "projection")
        require(self.derivative_bounds in DERIVATIVE_BOUNDS, f"projection.derivative_bounds must be one of "
                f"{', '.join(map(repr, DERIVATIVE_BOUNDS))}, got {self.derivative_bounds!r}")
        require(1 <= self.derivative_pieces <= 16,
                f"projection.derivative_pieces must be in [1, 16], got {self.derivative_pieces}")
        require(0 <= self.nearest_obstacles <= 1000,
                f"projection.nearest_obstacles must be in [0, 1000], got {self.nearest_obstacles}")
        require(self.nearest_choice in NEAREST_CHOICES, f"projection.nearest_choice must be one of "
                f"{', '.join(map(repr, NEAREST_CHOICES))}, got {self.nearest_choice!r}")
        require(self.nearest_obstacles == 0 or not self.barrier,
                "projection.nearest_obstacles > 0 needs projection.barrier = false (the barrier follows every obstacle)")
        require(1 <= self.obstacle_stride <= 16, f"projection.obstacle_stride must be in [1, 16], got {self.obstacle_stride}")
        require(0 <= self.obstacle_dense_time <= MAX_HORIZON,
                f"projection.obstacle_dense_time must be in [0, {MAX_HORIZON:g}] s, got {self.obstacle_dense_time:g}")
        require(self.obstacle_stride == 1 or not (self.barrier or self.nearest_obstacles),
                "projection.obstacle_stride > 1 needs projection.barrier = false and nearest_obstacles = 0 (the barrier "
                "follows every node; the nearest obstacles are chosen per node)")
        require(0 <= self.max_iterations <= 10_000, f"projection.max_iterations must be in [0, 10000], got {self.max_iterations}")
        require(0 <= self.early_iterations <= 10_000, f"projection.early_iterations must be in [0, 10000], got "
                f"{self.early_iterations}")
        require(self.tolerance >= 0, "projection.tolerance must be >= 0")
        for name in ("rho_obstacle", "rho_velocity", "rho_acceleration", "rho_lane"):
            value = getattr(self, name)
            require(0 < value <= MAX_WEIGHT, f"projection.{name} must be in (0, {MAX_WEIGHT:g}], got {value:g}")
        require(0 <= self.v_min < self.v_max <= MAX_SPEED, f"projection needs 0 <= v_min < v_max <= {MAX_SPEED:g} m/s")
        require(0 < self.a_max <= MAX_ACCELERATION, f"projection.a_max must be in (0, {MAX_ACCELERATION:g}] m/s^2")
        require(0 <= self.kappa_max <= 10, "projection.kappa_max must be in [0, 10] 1/m")
        require(0 < self.centripetal_max <= MAX_ACCELERATION, f"projection.centripetal_max must be in (0, {MAX_ACCELERATION:g}] m/s^2")
        require(0 <= self.recovery_time <= MAX_HORIZON, f"projection.recovery_time must be in [0, {MAX_HORIZON:g}] s")
        require(0 <= self.ego_turn_rate <= 10, f"projection.ego_turn_rate must be in [0, 10] rad/m, got {self.ego_turn_rate:g}")
        require(0 <= self.course_max < math.pi / 2, f"projection.course_max must be in [0, pi/2) rad, got {self.course_max:g}")
        require(0 <= self.course_min_speed <= MAX_SPEED,
                 f"projection.course_min_speed must be in [0, {MAX_SPEED:g}] m/s, got {self.course_min_speed:g}")
        require(0 <= self.anderson_window <= 8, f"projection.anderson_window must be in [0, 8], got {self.anderson_window}")
        require(0 < self.relaxation < 2, f"projection.relaxation must be in (0, 2), got {self.relaxation:g}")
        for name in ("gamma_obs", "gamma_lane"):
            value = getattr(self, name)
            require(0 < value <= 1, f"projection.{name} must be in (0, 1], got {value:g}")
            require(self.barrier or value == 1, f"projection.{name} = {value:g} needs projection.barrier = true "
                                                 "(the plain constraints have no barrier parameter)")


@dataclass(frozen=True)
class CostConfig:
    """Weights of the upper-level driving cost terms (each a mean over the nodes but ``lane_flow``, read at a plan's
    end), the nodes' weights, and the speed reference's slowing."""

    speed: float = 1.0  # [1/(m/s)^2] weight of (|v| - v_ref)^2, v_ref: v_des, or coming down to it (slowing)
    lateral_acceleration: float = 0.2  # [1/(m/s^2)^2] weight of y''^2
    heading: float = 20.0  # [1/rad^2] weight of the heading^2 relative to the road
    curvature: float = 10.0  # [m^2] weight of the curvature^2 (steering effort proxy)
    lane_centering: float = 0.5  # [1/m^2] weight of the squared distance of y(t) to the nearest lane centre
    consistency: float = 0.1  # [1/m^2] weight of (y(t) - y_previous(t))^2 against the previous replan's plan (0: not used, P1)
    route: float = 10.0  # [1/lane] weight of the lane changes still between y(t)'s lane and the band a route's split draws
    # it towards (PlanningProblem.pull_band; the term is 0 without one), counted from the nearest lane, so a plan stuck
    # between two lanes gains nothing over the nearer one
    lane_flow: float = 10.0  # [-] weight of ((v_des - v) / v_des)^2, v the speed of the slowest car ahead in the lane a plan
    # ends in (driveopt.costs.lane_flow; 0: not used, P1): what the plan will lose after its horizon behind it
    time_constant: float = 0.0  # [s] every term weighs the node at time t by exp(-t / this) (weighted means; 0: every
    # node alike, P1). A plan is made again long before its end, so what it gives up later costs less than the same
    # given up now: a plan closing on a slower car far ahead keeps its speed and slows when near, where plain means
    # have it slow a little from the start (the least squared shortfall spreads a deficit of distance evenly)
    slowing: float = 1.5  # [m/s^2] on a road of highway-env, a car that starts faster than its desired speed, where no
    # curve ahead lowers it, is asked to slow to it at this deceleration from its start speed (Scene.slowing_from; 0:
    # v_des from the first node, P1), not as hard as the plan's bounds allow: upstream's merge-v0 and two-way-v0 start
    # their car at 30 m/s in 20 m/s lanes. A car that started at or below its desired speed is asked for it throughout

    def __post_init__(self) -> None:
        check_types(self, "cost")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            require(0 <= value <= MAX_WEIGHT, f"cost.{f.name} must be in [0, {MAX_WEIGHT:g}], got {value:g}")


@dataclass(frozen=True)
class SamplerConfig:
    """Bi-level cross-entropy sampler (P1 Alg. 1, eq. 6)."""

    num_samples: int = 1000  # [-] n-bar, samples per iteration (P1); the registered ``bilevel`` plans 250
    # (real time: docs/results/speed.md), as the results' ``bilevel`` runs do
    num_iterations: int = 5  # [-] N, sampler iterations
    num_constraint_elites: int = 100  # [-] n, lowest-residual samples kept
    num_elites: int = 40  # [-] q, lowest (cost + residual) samples of those
    temperature: float = 0.9  # [-] gamma of P1 eq. 6c, in [1e-6, 1e6]
    learning_rate: float = 0.6  # [-] eta of P1 eq. 6a/6b
    covariance_jitter: float = 0.01  # [-] added to the covariance diagonal after each update
    speed_std: float = math.sqrt(30.0)  # [m/s] initial std of every speed set-point
    lateral_std: float = math.sqrt(46.0)  # [m] initial std of every lateral set-point
    residual_tolerance: float = 0.05  # [-] total residual under which a sample counts as feasible
    structured_fraction: float = 0.5  # [-] share of the first batch drawn as whole-horizon behaviours (0: P1)

    def __post_init__(self) -> None:
        check_types(self, "sampler")
        require(1 <= self.num_samples <= 100_000, f"sampler.num_samples must be in [1, 100000], got {self.num_samples}")
        require(1 <= self.num_iterations <= 1000, f"sampler.num_iterations must be in [1, 1000], got {self.num_iterations}")
        require(
            1 <= self.num_elites <= self.num_constraint_elites <= self.num_samples,
            "sampler needs 1 <= num_elites <= num_constraint_elites <= num_samples",
        )
        require(MIN_TEMPERATURE <= self.temperature <= MAX_WEIGHT,
                f"sampler.temperature must be in [{MIN_TEMPERATURE:g}, {MAX_WEIGHT:g}], got {self.temperature:g}")
        require(0 < self.learning_rate <= 1, "sampler.learning_rate must be in (0, 1]")
        require(0 <= self.covariance_jitter <= 1e3, "sampler.covariance_jitter must be in [0, 1000]")
        require(0 < self.speed_std <= MAX_SPEED and 0 < self.lateral_std <= 100, "sampler needs speed_std in (0, 100] m/s and lateral_std in (0, 100] m")
        require(0 <= self.residual_tolerance <= 1e3, "sampler.residual_tolerance must be in [0, 1000]")
        require(0 <= self.structured_fraction <= 1, "sampler.structured_fraction must be in [0, 1]")


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's maths: basis, set-point QP, projection, sampler and cost. Hashable: a jit static argument.

    What is not maths lives elsewhere: how rows are ranked, what rides in a batch, which stops the fallback weighs and
    whether repeated rows are projected once are the planner's method (:class:`driveopt.method.Method`: a
    :mod:`driveopt.ranking`, a :class:`driveopt.fallback.Fallback`, a :mod:`driveopt.row_sharing`); what only a
    closed-loop driver reads is in its spec
    (:class:`driveopt.drivers.optimiser.OptimiserSpec`).
    """

    basis: BasisConfig = field(default_factory=BasisConfig)
    qp: QPConfig = field(default_factory=QPConfig)
    projection: ProjectionConfig = field(default_factory=ProjectionConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    cost: CostConfig = field(default_factory=CostConfig)

    def __post_init__(self) -> None:
        work, sample_nodes = planning_work(self), self.sampler.num_samples * self.basis.num_nodes
        check_budget("planning work per call (samples x sampler iterations x projection iterations x nodes)", work,
                     MAX_PLANNING_WORK, f"about {_hours(work / PLANNING_WORK_PER_SECOND)} a call on 2 CPU cores")
        check_budget("planning memory per call (samples x nodes)", sample_nodes, MAX_SAMPLE_NODES,
                     f"about {sample_nodes * BYTES_PER_SAMPLE_NODE / 1e9:.1f} GB of working arrays")

    def replace(self, **sections: Mapping[str, Any] | Any) -> "PlannerConfig":
        """Copy with sections replaced; a mapping value updates fields of that section.

        >>> PlannerConfig().replace(sampler={"num_samples": 250}).sampler.num_samples
        250
        """
        return from_dict(sections, base=self)

    def with_samples(self, samples: int) -> "PlannerConfig":
        """Copy with ``samples`` per sampler iteration, the elite counts capped at it."""
        elites = min(self.sampler.num_constraint_elites, samples)
        return self.replace(sampler={"num_samples": samples, "num_constraint_elites": elites,
                                     "num_elites": min(self.sampler.num_elites, elites)})


# Estimates of one planning call (measured on 2 CPU cores with the dense-snapshot problem, 10 obstacles): it does
# about PLANNING_WORK_PER_SECOND units of planning_work a second and holds about BYTES_PER_SAMPLE_NODE bytes per
# sample and node. The limits are 1000 times the default call's work (1e7: ~0.5 s) and 200 times its memory
# (1e5 sample-nodes); DRIVEOPT_ALLOW_LARGE=1 lifts them (:func:`driveopt.checks.check_budget`).
PLANNING_WORK_PER_SECOND = 1e7  # [sample-node-iterations / s]
BYTES_PER_SAMPLE_NODE = 80  # [bytes]
MAX_PLANNING_WORK = 1e10  # [sample-node-iterations]
MAX_SAMPLE_NODES = 2e7  # [samples x nodes]


# Obstacles. The projection handles each obstacle in its own copy of the obstacle terms (a loop unrolled when the
# planner is traced: it fuses far better on the CPU than (samples, obstacles, nodes) arrays), so the compiled program,
# its compile time and the compiler's memory grow with the obstacle count whatever the batch, and every projection
# iteration's work grows with it too. Measured on the project's 2 shared CPU cores, one run each:
#   /usr/bin/time -v driveopt plan --samples 60 --max-obstacles N --repeats 1   (static-blockage, bilevel)
#   N = 10, 30, 60, 100 obstacles: compile 19, 22, 84, 108 s; solve 23, 35, 46, 1723 ms; peak RSS 0.73, 0.82, 1.03,
#   1.65 GB.
# Compilation: about COMPILE_SECONDS_PER_OBSTACLE and COMPILE_BYTES_PER_OBSTACLE per obstacle (the secants from 10 to
# 100); MAX_OBSTACLES, 10 times the default's (build_problem's and the drivers' 10), is the largest count measured
# (~2 minutes to compile, 1.7 GB). Work: up to 60 obstacles a call grows by 0.45 ms an obstacle on a 23 ms call at
# 10, so its work is that of OBSTACLE_WORK_OFFSET + N obstacles (:func:`obstacle_factor`); at 100 the solve was
# 27 times slower than that predicts (the unrolled loop no longer fuses), which MAX_OBSTACLES keeps out of reach
# unless DRIVEOPT_ALLOW_LARGE=1. Memory: the working arrays of the barrier projection hold one (samples, nodes) slice
# per obstacle (the ratios of the previous node), so BYTES_PER_SAMPLE_NODE, measured at 10 obstacles, is scaled by
# obstacles / 10 above 10.
REFERENCE_OBSTACLES = 10  # [-] the obstacles PLANNING_WORK_PER_SECOND and BYTES_PER_SAMPLE_NODE were measured with
OBSTACLE_WORK_OFFSET = 42.0  # [obstacles] the work of a projection iteration apart from its obstacles, in obstacles
COMPILE_SECONDS_PER_OBSTACLE = 1.0  # [s] (108 - 19 s) / 90 obstacles
COMPILE_BYTES_PER_OBSTACLE = 1.0e7  # [bytes] (1.65 - 0.73 GB) / 90 obstacles
MAX_OBSTACLES = 100  # [-] obstacles a planning call is compiled for


def obstacle_factor(obstacles: int) -> float:
    """[-] the work of a planning call against ``obstacles`` relative to one against REFERENCE_OBSTACLES."""
    return (OBSTACLE_WORK_OFFSET + obstacles) / (OBSTACLE_WORK_OFFSET + REFERENCE_OBSTACLES)


def planning_work(config: PlannerConfig, obstacles: int = REFERENCE_OBSTACLES) -> float:
    """[sample-node-iterations] the work of one planning call: every sampler iteration projects every sample (with
    ``projection.early_iterations`` iterations but in the last, where that is > 0), each projection iteration touching
    every node (an unprojected batch, max_iterations 0, still costs one pass), against
    ``obstacles`` (in units of a call against REFERENCE_OBSTACLES, :func:`obstacle_factor`)."""
    projection = config.projection
    iterations = (config.sampler.num_iterations - 1) * max(projection.earlier_iterations, 1) + max(projection.max_iterations, 1)
    return float(config.sampler.num_samples) * iterations * config.basis.num_nodes * obstacle_factor(obstacles)


def check_obstacles(obstacles: int) -> None:
    """ConfigError unless a planning call against ``obstacles`` (an integer >= 1) compiles within MAX_OBSTACLES (or
    the user opted in): its program grows with every obstacle, whatever the batch. Checked where the count is given
    (``build_problem``, ``driveopt plan --max-obstacles``) and again by ``plan``, before anything is allocated or
    compiled."""
    check_count("max_obstacles", obstacles)
    check_budget("obstacles a planning call is compiled for (max_obstacles)", obstacles, MAX_OBSTACLES,
                 f"about {_hours(obstacles * COMPILE_SECONDS_PER_OBSTACLE)} and "
                 f"{obstacles * COMPILE_BYTES_PER_OBSTACLE / 1e9:.3g} GB to compile on 2 CPU cores")


def check_planning_size(config: PlannerConfig, obstacles: int) -> None:
    """ConfigError unless one planning call of ``config`` against ``obstacles`` is within the compile, work and memory
    limits (or the user opted in): :class:`PlannerConfig` checks its own sizes at the reference obstacle count, this
    counts the obstacles given (samples x sampler iterations x projection iterations x nodes x obstacles)."""
    check_obstacles(obstacles)
    work = planning_work(config, obstacles)
    check_budget(f"planning work per call against {obstacles} obstacles (samples x sampler iterations x projection "
                 "iterations x nodes, x the obstacles' share)", work, MAX_PLANNING_WORK,
                 f"about {_hours(work / PLANNING_WORK_PER_SECOND)} a call on 2 CPU cores")
    sample_nodes = config.sampler.num_samples * config.basis.num_nodes * max(obstacles, REFERENCE_OBSTACLES) / REFERENCE_OBSTACLES
    check_budget(f"planning memory per call against {obstacles} obstacles (samples x nodes x obstacles / "
                 f"{REFERENCE_OBSTACLES})", sample_nodes, MAX_SAMPLE_NODES,
                 f"about {sample_nodes * BYTES_PER_SAMPLE_NODE / 1e9:.1f} GB of working arrays")


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.3g} hours" if seconds >= 3600 else f"{seconds / 60:.3g} minutes"


_SECTIONS = {
    "basis": BasisConfig,
    "qp": QPConfig,
    "projection": ProjectionConfig,
    "sampler": SamplerConfig,
    "cost": CostConfig,
}


# Fields that are inputs of the compiled planner rather than constants compiled into it: configurations that differ
# only in these share one compilation (a sweep over the cost weights, a car with another acceleration bound). Each is
# read only by array arithmetic inside the planner, and the results are bit for bit those of the value compiled in
# (tests/core/test_behaviours.py). The others stay constants: counts and switches shape the program, some bounds
# turn a constraint off at 0 (kappa_max, course_max, recovery_time, ego_turn_rate), and XLA rounds arithmetic on some
# compiled-in values differently (sampler.temperature, a divisor; the projection's penalty weights): their results
# would differ in the last bits, and a closed loop amplifies that into another episode.
RUNTIME_FIELDS: dict[str, tuple[str, ...]] = {
    "projection": ("v_min", "a_max"),
    "cost": ("speed", "lateral_acceleration", "heading", "curvature", "lane_centering", "consistency", "route",
             "lane_flow"),
}


@functools.lru_cache(maxsize=64)
def split_runtime(config: PlannerConfig) -> tuple[PlannerConfig, dict[str, dict[str, np.float32]]]:
    """(``config`` with its :data:`RUNTIME_FIELDS` at their defaults, their values as float32 by section and name):
    what the compiled planner is specialised to, and what it takes as inputs (cached: a closed loop splits the same
    configuration at every step; treat the values as read-only)."""
    default = PlannerConfig()
    values = {section: {name: np.float32(getattr(getattr(config, section), name)) for name in names}
              for section, names in RUNTIME_FIELDS.items()}
    static = config.replace(**{section: {name: getattr(getattr(default, section), name) for name in names}
                               for section, names in RUNTIME_FIELDS.items()})
    return static, values


def with_runtime(config: PlannerConfig, values: Mapping[str, Mapping[str, Any]]) -> PlannerConfig:
    """``config`` holding ``values`` (by section and field name, from :func:`split_runtime`) in its runtime fields.
    The values may be arrays or JAX tracers, so they are not validated: they come from a checked configuration."""
    sections = {}
    for section, fields in values.items():
        sections[section] = part = copy.copy(getattr(config, section))
        for name, value in fields.items():
            object.__setattr__(part, name, value)
    whole = copy.copy(config)
    for section, part in sections.items():
        object.__setattr__(whole, section, part)
    return whole


def from_dict(data: Mapping[str, Any], base: PlannerConfig | None = None) -> PlannerConfig:
    """Build a PlannerConfig from a nested mapping, rejecting unknown keys with a clear message."""
    base = base or PlannerConfig()
    if not isinstance(data, Mapping):
        raise ConfigError(f"planner config must be a mapping, got {type(data).__name__}")
    updates: dict[str, Any] = {}
    for key, value in data.items():
        if key in _SECTIONS:
            section = getattr(base, key)
            if isinstance(value, _SECTIONS[key]):
                updates[key] = value
                continue
            if not isinstance(value, Mapping):
                raise ConfigError(f"config section '{key}' must be a mapping")
            known = {f.name for f in dataclasses.fields(section)}
            unknown = sorted(set(value) - known)
            if unknown:
                raise ConfigError(f"unknown key(s) in '{key}': {unknown}; valid: {sorted(known)}")
            try:
                updates[key] = dataclasses.replace(section, **value)
            except TypeError as exc:
                raise ConfigError(f"bad value in '{key}': {exc}") from None
        else:
            raise ConfigError(f"unknown config section '{key}'; valid: {sorted(_SECTIONS)}")
    return dataclasses.replace(base, **updates)


def to_dict(config: PlannerConfig) -> dict[str, Any]:
    """Plain nested dict (JSON-serialisable) of a PlannerConfig."""
    return dataclasses.asdict(config)
