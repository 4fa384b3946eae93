"""The bi-level optimiser (and every baseline built on it) as a closed-loop driver.

Each policy step the driver perceives the simulator once (:func:`driveopt.sim.perception.perceive`),
builds the planning problem (same-lane followers left out), plans with the spec's prior and
configuration, and turns the plan's first action period into a ``ContinuousAction`` by the exact
inverse of upstream's bicycle model. It carries the sampling mean to the next call when the spec
warm-starts, and the executed plan when its configuration weighs ``cost.consistency``. When the
planner reports anything but SUCCESS it follows the fallback and brakes at once at the fallback's
deceleration, except where it plans against crossing traffic (a :class:`~driveopt.prediction.PathNeighbour`) and
the chosen plan meets the predicted traffic later than the fallback's stop does (``commits_at_crossings``,
:func:`driveopt.fallback.meets_later`): crossing traffic brakes only for a car on its own lane, so a stop inside a
junction is no harbour (at intersection-v0 a car that entered on a thin gap, found every plan infeasible a second
later and braked in the junction was struck by the car it had passed in front of). How the loop runs around the
planner is the spec's :class:`ClosedLoop` (``spec.loop``): with ``executes_infeasible`` (P1) it tracks the chosen
plan whatever its residual, and follows the fallback only on NUMERICAL_ERROR. Neighbours are predicted
braking-aware (:data:`driveopt.prediction.BRAKING_TIME`) unless ``braking_prediction`` is False (P1: constant
velocity), their lateral motion ending at their target lane's centre
unless ``target_lanes`` is False (P1: at their lateral rate), and the neighbours planned against are those that come
closest within :data:`driveopt.prediction.SELECTION_TIME` unless ``approach_selection`` is False (P1: the nearest
now). With ``replan_every`` N > 1 (P1 §V executes five control periods per plan) it
plans every N-th step and tracks the same plan open-loop in between. With a real-time ``latency``
(:mod:`driveopt.drivers.latency`) the same open-loop tracking pays for planning time: a plan started at step k
takes effect L policy periods later (its compute time rounded up, at least one); until then the car keeps tracking
the plan in effect. So that the new plan starts where the car will be when it takes effect, a call started at step
k plans from the scene predicted P periods ahead (P: the periods the previous call took, or the fixed latency's;
the ego moved by this step's command, then as the plan in effect moves it; the neighbours at constant velocity):
it takes effect after max(L, P) periods and is tracked from max(L - P, 0) into it. (Planned from the state at step
k, each plan would meet the car a period away from its start, and the tracker's correction within one period would
make the loop alternate between full throttle and full braking.) A new call starts at the step the previous one is
delivered, and no sooner than N steps after it started: one call in flight at a time. The episode's first plan is
made synchronously (the simulator waits for it). Its PRNG key derives from the
episode seed: same seed, same episode. A learned safety filter (P2 §III-C; ``filter_weights``, or the
shipped weights for a spec with ``learned_filter``) sets up every batch's projection
(:mod:`driveopt.safety.learned`). With the loop's ``contact_guard``, a command at crawling speed that would take
the ego's box within 0.1 m of a car's, where braking now would keep it further, is replaced by braking now
(:mod:`driveopt.sim.contact`). The spec's ``method`` (:class:`driveopt.method.Method`) is the planner's strategies
(:func:`driveopt.planner.solve`), its fallback's comfortable braking capped at what the car can do: the papers' planners
swap the ranking and the fallback for the papers'; P2's pipelines project repeated rows once. A planner as the papers'
authors ran it is driveopt's with the papers' ``method`` and ``loop`` (:data:`PAPERS_LOOP`; :mod:`driveopt.faithful`).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Any, Callable, NamedTuple

import jax
import numpy as np

from driveopt.checks import check_count, check_types
from driveopt.config import PlannerConfig, to_dict
from driveopt.drivers.base import Decision, DriverSpec
from driveopt.drivers.commands import EXACT_TRACKING, ExactTracking, FirstNodesMean
from driveopt.drivers.latency import Latency, Synchronous, parse_latency
from driveopt.fallback import Fallback, meets_later
from driveopt.files import json_digest, pytree_digest
from driveopt.method import DRIVEOPT_METHOD, Method
from driveopt.multi_plan import Call
from driveopt.planner import PlanResult, PlanStatus, PreviousPlan, plan, previous_plan
from driveopt.prediction import BRAKING_TIME, SELECTION_TIME, PathNeighbour
from driveopt.problem import build_problem
from driveopt.qp import NUM_SEGMENTS, SETPOINT_DIM
from driveopt.sim.contact import guard
from driveopt.sim.control import (BicycleModel, Command, EgoKinematics, brake_at_least, ego_kinematics, predict,
                                  sample_trajectory, track)
from driveopt.sim.perception import Perception, RoadPreview, perceive
from driveopt.sim.road_frame import RoadFrameError, slip_angle
from driveopt.sim.scenarios import Scenario
from driveopt.sim.world_plan import to_world

SAFETY_FACTOR = 0.9  # [-] plans use at most this fraction of the simulator's acceleration and curvature
FRAME_SHIFT_TOLERANCE = 1e-4  # [m] a change of the car's lateral coordinate between two frames above this is a jump
# of the frame's lateral origin (frames along the same roads give the same d to float precision)
MIN_PLANNING_CURVATURE = 0.02  # [1/m] path curvature a plan must keep on top of the road's (a 50 m radius)

PriorFactory = Callable[[PlannerConfig, int, "str | None"], Any]  # (config, lanes, weights file) -> prior
FilterFactory = Callable[[PlannerConfig, int, "str | None"], Any]  # (config, lanes, weights file) -> safety filter or None
CommandRule = ExactTracking | FirstNodesMean  # (followed plan, elapsed [s], speed and heading, car model) -> Command


def vehicle_acceleration(model: BicycleModel) -> float:
    """[m/s^2] the acceleration plans may use: SAFETY_FACTOR of the smaller end of the car's ``acceleration_range``."""
    return SAFETY_FACTOR * min(abs(model.acceleration_range[0]), abs(model.acceleration_range[1]))


def adapt_to_vehicle(config: PlannerConfig, model: BicycleModel, road_curvature: float = 0.0) -> PlannerConfig:
    """Cap the planner's acceleration and curvature bounds at what the simulated car can do.

    Upstream's ego accelerates within ``acceleration_range`` and turns at most with curvature
    2 sin(beta_max) / L, beta_max = arctan(tan(delta_max) / 2). Plans are made in the road frame, where a path's
    curvature is what it turns on top of the road's: the bound leaves ``|road_curvature|`` [1/m] (the sharpest
    curve of the route) to the road. RoadFrameError when the road turns tighter than the car can.
    """
    a_max = vehicle_acceleration(model)
    beta_max = math.atan(0.5 * math.tan(max(abs(s) for s in model.steering_range)))
    car_kappa = SAFETY_FACTOR * 2.0 * math.sin(beta_max) / model.length
    kappa_max = car_kappa - abs(road_curvature)
    if road_curvature != 0.0 and kappa_max < MIN_PLANNING_CURVATURE:
        raise RoadFrameError(f"the route curves with radius {1.0 / abs(road_curvature):.1f} m; with its steering range "
                             f"{model.steering_range} rad the car turns no tighter than {1.0 / car_kappa:.1f} m "
                             f"(with the planner's {SAFETY_FACTOR} safety factor), leaving no curvature to manoeuvre")
    projection = dataclasses.replace(
        config.projection,
        a_max=min(config.projection.a_max, a_max),
        kappa_max=min(config.projection.kappa_max, kappa_max) if config.projection.kappa_max > 0 else kappa_max,
    )
    return dataclasses.replace(config, projection=projection)


def adapt_fallback(fallback: Fallback, model: BicycleModel) -> Fallback:
    """``fallback`` braking comfortably at no more than the car can (:func:`vehicle_acceleration`)."""
    return dataclasses.replace(fallback, deceleration=min(fallback.deceleration, vehicle_acceleration(model)))


@dataclasses.dataclass(frozen=True)
class ClosedLoop:
    """How a closed loop runs around the planner: what it executes, how it predicts and picks the neighbours it plans
    against, whether it guards commands at crawling speed, and how often it plans; driveopt's by default, the papers'
    in :data:`PAPERS_LOOP` (:meth:`papers`)."""

    replan_every: int = 1  # [policy periods] each plan is executed for this many periods (P1 §V: 5)
    executes_infeasible: bool = False  # track the chosen plan even when INFEASIBLE, no brake-now fallback (P1)
    braking_prediction: bool = True  # braking neighbours keep braking for BRAKING_TIME (False: constant velocity, P1)
    approach_selection: bool = True  # plan against the neighbours closest within SELECTION_TIME (False: nearest now, P1)
    contact_guard: bool = True  # brake now when a command at crawling speed would take the ego's box within 0.1 m of a
    # car's and braking now would not (driveopt.sim.contact; not for drivers that execute infeasible plans, P1)
    measured_start: bool = True  # a plan starts at the car's measured acceleration (False: at zero, P2's authors)
    command: CommandRule = EXACT_TRACKING  # how the followed plan becomes the period's command (driveopt.drivers.commands)
    target_lanes: bool = True  # a neighbour's lateral motion is predicted to end at the centre of the lane it steers to
    # (driveopt.sim.perception.RoadPreview.target_lanes; False: at its lateral rate for the whole horizon, P1)
    commits_at_crossings: bool = True  # where crossing traffic is planned against, an INFEASIBLE plan that meets it later
    # than the fallback's stop is followed instead of the stop (:func:`meets_later`; False: the stop, as on any road)

    def __post_init__(self) -> None:
        check_types(self, "loop")
        check_count("replan_every", self.replan_every)

    @classmethod
    def papers(cls, replan_every: int) -> "ClosedLoop":
        """The papers' loop: the chosen plan executed whatever its residual, no contact guard, constant-velocity
        prediction (lateral too) of the nearest neighbours now, a plan every ``replan_every`` policy periods."""
        return cls(replan_every=replan_every, executes_infeasible=True, braking_prediction=False,
                   approach_selection=False, contact_guard=False, target_lanes=False, commits_at_crossings=False)

    @property
    def braking_time(self) -> float:
        """[s] how long the planning problem predicts a braking neighbour to keep braking (0: constant velocity)."""
        return BRAKING_TIME if self.braking_prediction else 0.0

    @property
    def selection_time(self) -> float:
        """[s] look-ahead of the obstacle selection (0: the nearest neighbours now)."""
        return SELECTION_TIME if self.approach_selection else 0.0


DRIVEOPT_LOOP = ClosedLoop()  # driveopt's: the safe trajectory executed, braking-aware and approach-ranked, guarded
PAPERS_LOOP = ClosedLoop.papers(replan_every=1)  # as the papers' authors ran their planners: a plan every period


def _present(previous: PreviousPlan | None) -> bool:
    """Whether a previous plan is carried (not None, nor the absent placeholder)."""
    return previous is not None and bool(previous.present)


@dataclasses.dataclass(frozen=True)
class OptimiserSpec(DriverSpec):
    """A planner run by :func:`driveopt.planner.plan`: a configuration and a prior factory."""

    config: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    make_prior: PriorFactory | None = None  # None: the Gaussian prior of ``config.sampler``
    warm_start: bool = False  # carry the sampling mean between replans
    weights: str | None = None  # learned priors: checkpoint file (default: the weights shipped for the road)
    fixed_batch: bool = False  # the batch size is part of the method (vanilla: one sample); with_samples keeps it
    learned_filter: bool = False  # project with the learned safety filter shipped for the road (none: the plain filter, warned)
    filter_weights: str | None = None  # learned safety filter checkpoint for any optimiser (default: none, or the shipped one)
    make_filter: FilterFactory | None = None  # a filter that comes with the prior's ``weights`` (cvae-multipliers:
    # the multiplier head of the same checkpoint); ``filter_weights`` replaces it with P2's learned filter
    learned_prior: bool = False  # ``make_prior`` loads a learned checkpoint: ``weights`` names it (else no weights)
    method: Method = DRIVEOPT_METHOD  # how the planner ranks a batch, what rides in it, its fallback, its row sharing
    loop: ClosedLoop = DRIVEOPT_LOOP  # how the closed loop runs around the planner (the papers': PAPERS_LOOP)
    latency: Latency = Synchronous()  # how planning time delays a plan (driveopt.drivers.latency; default: the sim waits)

    def __post_init__(self) -> None:
        check_types(self, "")

    @property
    def braking_time(self) -> float:
        """[s] how long the planning problem predicts a braking neighbour to keep braking (``loop.braking_time``)."""
        return self.loop.braking_time

    @property
    def selection_time(self) -> float:
        """[s] look-ahead of the obstacle selection (``loop.selection_time``)."""
        return self.loop.selection_time

    @property
    def is_optimiser(self) -> bool:
        return True

    @property
    def takes_weights(self) -> bool:
        return self.learned_prior

    def prior(self, lanes: int = 4) -> Any:
        """The first-iteration proposal for a road with ``lanes`` lanes (learned priors pick weights by it)."""
        if self.make_prior is None:
            from driveopt.sampler import GaussianPrior

            return GaussianPrior.from_config(self.config.sampler, self.config.projection.v_max)
        return self.make_prior(self.config, lanes, self.weights)

    def safety_filter(self, lanes: int = 4) -> Any:
        """The learned safety filter for a road with ``lanes`` lanes (``filter_weights``, or the shipped weights when
        ``learned_filter``), or the one ``make_filter`` makes from ``weights``, or None: the projection as configured.
        CheckpointError for unusable or wrong-road weights."""
        if self.filter_weights is None and not self.learned_filter:
            return None if self.make_filter is None else self.make_filter(self.config, lanes, self.weights)
        from driveopt.safety.learned import filter_for

        learned = filter_for(lanes, self.filter_weights)
        if learned is not None and not self.config.projection.barrier:
            warnings.warn(f"{self.name}: the learned safety filter's gammas act only in barrier mode; this projection is plain "
                          "(add {\"projection\": {\"barrier\": true}} to --config to use them)", stacklevel=2)
        return learned

    def driver(self) -> "OptimiserDriver":
        return OptimiserDriver(self)

    def check(self, scenario: Scenario) -> None:
        self.prior(scenario.lanes)
        self.safety_filter(scenario.lanes)

    def weights_digest(self, scenario: Scenario) -> str | None:
        """Digest of the learned prior's and learned filter's arrays for ``scenario``'s road; None for a Gaussian
        prior without a learned filter."""
        learned = [part for part in (self.make_prior and self.prior(scenario.lanes), self.safety_filter(scenario.lanes))
                   if part is not None]
        return pytree_digest(learned) if learned else None

    def config_digest(self) -> str:
        """Digest of :attr:`config` (every field, defaults included)."""
        return json_digest(to_dict(self.config))

    def with_overrides(self, **sections: Any) -> "OptimiserSpec":
        """Copy with config sections updated, e.g. ``sampler={"num_samples": 250}``; a ``safety_filter`` section
        ``{"weights": FILE}`` names a learned filter checkpoint (:meth:`with_filter_weights`)."""
        from driveopt.safety.learned import split_filter_section

        sections, weights = split_filter_section(sections)
        spec = dataclasses.replace(self, config=self.config.replace(**sections))
        return spec.with_filter_weights(weights) if weights is not None else spec

    def with_filter_weights(self, weights: str | None) -> "OptimiserSpec":
        """Copy that projects with the learned safety filter of the checkpoint ``weights`` (unchanged for ``None``)."""
        return self if weights is None else dataclasses.replace(self, filter_weights=weights)

    def with_samples(self, samples: int | None) -> "OptimiserSpec":
        """Copy with ``samples`` per sampler iteration (elite counts capped at it); unchanged for ``None``
        and for planners whose batch size is part of the method (``fixed_batch``)."""
        if samples is None or self.fixed_batch:
            return self
        return dataclasses.replace(self, config=self.config.with_samples(samples))

    def with_weights(self, weights: str | None) -> "OptimiserSpec":
        """Copy that loads a learned prior from ``weights`` (a checkpoint file)."""
        return dataclasses.replace(self, weights=weights)

    def with_replan_every(self, periods: int | None) -> "OptimiserSpec":
        """Copy that executes each plan for ``periods`` policy periods (unchanged for ``None``)."""
        return self if periods is None else dataclasses.replace(self, loop=dataclasses.replace(self.loop, replan_every=periods))

    def with_latency(self, latency: Any) -> "OptimiserSpec":
        """Copy whose plans take effect after their planning time (:func:`driveopt.drivers.latency.parse_latency`:
        ``"sync"``, ``"measured"`` or a compute time [ms]); unchanged for ``None``. LatencyError for other values."""
        return self if latency is None else dataclasses.replace(self, latency=parse_latency(latency))


class Shared(NamedTuple):
    """What planning calls of several episodes must share to be solved together (:func:`driveopt.multi_plan.plan_many`)."""

    config: PlannerConfig  # adapted to the car (adapt_to_vehicle)
    prior: Any
    safety_filter: Any
    method: Method


class _Call(NamedTuple):
    """One planning call: its result, what it planned from, and when it takes effect."""

    index: int  # [-] the episode's planning calls, counted from 0
    result: PlanResult
    world: Any  # the trajectory the car follows (``followed``) in world coordinates
    scene: Any
    problem: Any
    frame: Any  # the road frame it planned in
    seconds: float  # [s] measured wall time of the call
    periods: int  # [policy periods] its compute time, rounded up (0: it takes effect at the step it started)
    ahead: int  # [policy periods] from the step it started to its plan's t = 0 (the scene it planned from)
    commits: bool = False  # the car follows its chosen plan though INFEASIBLE (ClosedLoop.commits_at_crossings)

    @property
    def delivered_after(self) -> int:
        """[policy periods] from the step it started to the step it takes effect."""
        return max(self.periods, self.ahead)


class OptimiserDriver:
    """Plans every policy step; see the module docstring."""

    def __init__(self, spec: OptimiserSpec) -> None:
        self.spec = spec
        self.name = spec.name
        self.compile_seconds = 0.0

    def reset(self, env: Any, scenario: Any, seed: int, *, warm_up: bool = True, policy_frequency: float | None = None
              ) -> None:
        """Adapt the configuration to the env's car and road, load the prior, and compile (timed as ``compile_seconds``;
        ``warm_up`` False: no warm-up call, ``compile_seconds`` 0, for a caller that plans through
        :func:`driveopt.multi_plan.plan_many` and compiles that; the episode is the same either way).

        The car's acceleration and steering ranges, its length, the simulation and policy frequencies and the road
        are read from ``env``; ``scenario`` (a :class:`~driveopt.sim.scenarios.Scenario` or a
        :class:`~driveopt.sim.perception.Task`) gives only the desired speed, a name and optionally a route.
        ``policy_frequency`` [Hz]: how often ``act`` will be called, where that is not at each of the env's policy steps
        (the :class:`~driveopt.controller.Controller` planning within the env's period: a multiple of the env's
        policy frequency that divides its simulation frequency); default the env's."""
        self.scenario = scenario
        self.model = BicycleModel.from_env(env, policy_frequency)
        self._one_step = dataclasses.replace(self.model, steps_per_action=1)  # the car over one simulation step
        self.preview = RoadPreview(lateral_acceleration=self.spec.config.projection.centripetal_max,
                                   slowing=self.spec.config.cost.slowing, target_lanes=self.spec.loop.target_lanes)
        hz = env.unwrapped.config["policy_frequency"] if policy_frequency is None else policy_frequency
        self.period = 1.0 / hz  # [s] one policy period: between two calls of act
        first = perceive(env, scenario, self.preview, self.period)
        self.config = adapt_to_vehicle(self.spec.config, self.model, first.frame.curvature_between(-math.inf, math.inf))
        self.method = dataclasses.replace(self.spec.method, fallback=adapt_fallback(self.spec.method.fallback, self.model))
        lanes = first.scene.road.num_lanes
        self.prior = self.spec.prior(lanes)
        self.safety_filter = self.spec.safety_filter(lanes)
        self.key = jax.random.PRNGKey(seed)
        self.carries_plan = self.config.cost.consistency > 0
        # The first call passes the absent placeholder of the previous plan that later calls carry (a missing warm
        # start plan() runs as an absent one itself): every call runs one compilation, made here, outside the timed
        # loop (the result is discarded).
        self.warm = None
        self.previous = PreviousPlan.absent(self.config.basis.num_nodes) if self.carries_plan else None
        self._carried_frame = None  # the frame the carried warm start and previous plan are in
        self._slowing_from, self._slowing_at = 0.0, None  # [m/s] the most asked for, [s] when (None: not yet)
        self._first_scene, self._first_goal = self._let_slow(env, first.scene), first.goal
        self.compile_seconds = 0.0
        if warm_up:
            start = time.perf_counter()
            call = self.warm_up_call()
            plan(call.problem, self.config, key=call.key, prior=self.prior, warm_start=call.warm_start,
                 previous=call.previous, safety_filter=self.safety_filter, method=self.method)
            self.compile_seconds = time.perf_counter() - start
        self.executing: _Call | None = None  # the plan in effect
        self.executed_periods = 0  # [policy periods] into the plan in effect at the current step
        self.pending: _Call | None = None  # a plan computed but not yet in effect (real-time latency)
        self.steps = 0  # [-] policy steps acted this episode
        self._step: tuple[_Call, float, bool] | None = None  # the latest step's (plan followed, [s] into it, guarded)
        self.started_at = 0  # [-] the step the latest planning call started at
        self.expected = self.spec.latency.periods(0.0, self.period)  # [policy periods] a call's expected compute time

    def warm_up_call(self) -> Call:
        """The call that :meth:`reset` compiles with (the episode's first scene, a key the episode never draws): its
        result is discarded, and it leaves the driver as it was."""
        return Call(self._problem(self._first_scene, self._first_goal), jax.random.fold_in(self.key, 1), self.warm,
                    self.previous)

    def _let_slow(self, env: Any, scene: Any) -> Any:
        """``scene`` with the most a plan is asked for now (:attr:`Scene.slowing_from`): where the scene lets a car slow
        (``scene.slowing`` > 0), the car's speed at the episode's first scene, less ``slowing`` times the time since,
        down to the desired speed; elsewhere the desired speed. So a car that starts faster than its desired speed
        slows at that rate, and one that started at or below it is asked for it whatever it overshoots."""
        now = float(env.unwrapped.time)
        if scene.slowing > 0.0:
            start, then = ((math.hypot(scene.ego.vx, scene.ego.vy), now) if self._slowing_at is None
                           else (self._slowing_from, self._slowing_at))
            self._slowing_from = max(scene.v_des, start - scene.slowing * (now - then))
        else:
            self._slowing_from = scene.v_des
        self._slowing_at = now
        return dataclasses.replace(scene, slowing_from=self._slowing_from)

    def _problem(self, scene: Any, goal: Any = None):
        """The planning problem of ``scene``; ``goal``: the route's lanes at a split ahead (perception's), or None."""
        if not self.spec.loop.measured_start:
            scene = dataclasses.replace(scene, ego=dataclasses.replace(scene.ego, ax=0.0, ay=0.0))
        return build_problem(scene, self.config.basis, ignore_followers=True, braking_time=self.spec.braking_time,
                             selection_time=self.spec.selection_time, goal=goal)

    def _carried(self, result: PlanResult, gap: float):
        """(warm start, previous plan) handed to the next call, which starts ``gap`` [s] after ``result``'s."""
        previous = previous_plan(result, gap) if self.carries_plan else None
        return (result.mean if self.spec.warm_start else None), previous

    def _executes_chosen(self, result: PlanResult) -> bool:
        """Whether the car follows the chosen plan whatever its status (P1), not the safe trajectory."""
        return self.spec.loop.executes_infeasible and result.status != PlanStatus.NUMERICAL_ERROR

    def _brakes_now(self, result: PlanResult, commits: bool) -> bool:
        """Whether the car follows ``result``'s fallback, braking at once: not SUCCESS, not executed whatever its
        status (P1), not ``commits``."""
        return result.status != PlanStatus.SUCCESS and not commits and not self._executes_chosen(result)

    def followed(self, result: PlanResult, commits: bool = False) -> Any:
        """The trajectory of ``result`` the car follows (road frame): the chosen plan (P1, unless NUMERICAL_ERROR; or
        where it ``commits`` to it, :meth:`_commits`) or the safe trajectory (the plan when SUCCESS, else the fallback)."""
        return result.trajectory if commits or self._executes_chosen(result) else result.safe_trajectory

    def _commits(self, result: PlanResult, scene: Any, problem: Any) -> bool:
        """Whether the car follows ``result``'s chosen plan though INFEASIBLE: with the loop's ``commits_at_crossings``,
        where ``scene`` holds crossing traffic and the plan meets the predicted traffic later than the fallback does."""
        return (self.spec.loop.commits_at_crossings and result.status == PlanStatus.INFEASIBLE
                and any(isinstance(n, PathNeighbour) for n in scene.neighbours)
                and meets_later(problem, result.trajectory, result.fallback, result.x_offset))

    def act(self, env: Any) -> Decision:
        call = self.prepare(env)
        if call is None:
            return self.finish(env)
        start = time.perf_counter()
        result = plan(call.problem, self.config, key=call.key, prior=self.prior, warm_start=call.warm_start,
                      previous=call.previous, safety_filter=self.safety_filter, x_offset=call.x_offset, method=self.method)
        return self.finish(env, result, time.perf_counter() - start)

    def prepare(self, env: Any) -> Call | None:
        """The first half of :meth:`act`: the planning call this step starts (the arguments of ``plan`` that differ
        between episodes; the shared ones are :meth:`shared`), or None when none starts. Then :meth:`finish` with
        its result, so that several episodes' calls can be solved together (:func:`driveopt.multi_plan.plan_many`)."""
        self._delivered = self._deliver()
        self._perception = self._command_now = None
        self._guarded = False
        if not self._starts_call():
            if self.spec.loop.contact_guard:
                self._perception = perceive(env, self.scenario, self.preview, self.period)
            return None
        perception = perceive(env, self.scenario, self.preview, self.period)
        perception = self._perception = perception._replace(scene=self._let_slow(env, perception.scene))
        if self._ahead():  # the plan in effect carries the car until the new one takes effect: command it first
            self._command_now, self._guarded = self._step_command(env, perception)
        ahead = self._ahead() if self._command_now is not None else 0
        scene = self._predicted(perception, ahead, self._command_now) if ahead else perception.scene
        problem = self._problem(scene, perception.goal)
        self.key, sub = jax.random.split(self.key)
        self._request = (scene, problem, ahead)
        self._carry_into(env, perception)
        return Call(problem, sub, self.warm, self.previous, scene.ego.x)

    def shared(self) -> Shared:
        """What this driver's planning calls share with other episodes' (configuration, prior, filter, method)."""
        return Shared(self.config, self.prior, self.safety_filter, self.method)

    def finish(self, env: Any, result: PlanResult | None = None, seconds: float = 0.0) -> Decision:
        """The second half of :meth:`act`: the step's decision, given the ``result`` of the call :meth:`prepare`
        started (None when it started none) and its wall time ``seconds`` [s]."""
        delivered, perception, command, guarded = self._delivered, self._perception, self._command_now, self._guarded
        if result is not None:
            call = self._called(result, seconds)
            if call.periods == 0:
                delivered = self._take_effect(call)
            else:
                self.pending = call
        executing, elapsed = self.executing, self.executed_periods * self.period
        if command is None:
            command, guarded = self._step_command(env, perception)
        self._step = (executing, elapsed, guarded)
        action = command.action
        self.executed_periods += 1
        self.steps += 1
        if delivered is None:
            return Decision(action, guarded=guarded, plan_index=executing.index, plan_elapsed=elapsed)
        periods = delivered.periods if self.spec.latency.realtime else None
        return Decision(action, delivered.result, delivered.scene, delivered.problem, delivered.seconds, guarded,
                        delivered.frame, delivered.world, periods, executing.index, elapsed)

    def _starts_call(self) -> bool:
        """Whether a planning call starts at this step: the episode's first, or none in flight and ``replan_every``
        steps since the latest started."""
        if self.executing is None:
            return True
        return self.pending is None and self.steps - self.started_at >= self.spec.loop.replan_every

    def _ahead(self) -> int:
        """[policy periods] how far ahead of now a call started now plans: 0 synchronously and for the episode's first
        call, else the expected compute time."""
        return 0 if self.executing is None or not self.spec.latency.realtime else self.expected

    def within_period(self, env: Any, offset: float) -> Command | None:
        """The command for the simulation step ``offset`` [s] into the latest step's policy period, from the ego's
        state now: the plan that step's action follows, tracked over this simulation step alone (the exact inverse
        with one step, :func:`driveopt.sim.control.track`: the course after the step is the plan's then), braking now
        where that is the fallback; None where the step's action stands for the whole period (no step acted yet, the
        contact guard braked, or the loop's command is not the exact inverse, as P2's authors' mean of the first
        nodes)."""
        if self._step is None:
            return None
        executing, elapsed, guarded = self._step
        if guarded or not isinstance(self.spec.loop.command, ExactTracking):
            return None
        command = track(executing.world, elapsed + offset, ego_kinematics(env), self._one_step)
        if self._brakes_now(executing.result, executing.commits):
            command = brake_at_least(command, executing.result.fallback_deceleration, self._one_step,
                                     float(env.unwrapped.vehicle.speed))
        return command

    def _step_command(self, env: Any, perception: Perception | None) -> tuple[Command, bool]:
        """(the command of this step for the plan in effect, whether the contact guard replaced it)."""
        tracking = perception.tracking if perception else ego_kinematics(env)
        return self._command(self.executing.result, self.executing.world, self.executed_periods * self.period, tracking,
                             env, perception, self.executing.commits)

    def _called(self, result: PlanResult, seconds: float) -> _Call:
        """The call :meth:`prepare` started, finished with ``result`` after ``seconds`` [s] of wall time."""
        scene, problem, ahead = self._request
        index = 0 if self.executing is None else self.executing.index + 1
        periods = 0 if self.executing is None else self.spec.latency.periods(seconds, self.period)
        self.started_at = self.steps
        commits = self._commits(result, scene, problem)
        world = to_world(self.followed(result, commits), self._perception.frame)  # in world coordinates, for tracking
        return _Call(index, result, world, scene, problem, self._perception.frame, seconds, periods, ahead, commits)

    def _predicted(self, perception: Perception, ahead: int, command: Command) -> Any:
        """The scene of ``perception`` (the road frame now) ``ahead`` policy periods later, as a plan started now meets
        it: the ego moved by this step's ``command`` over the first period (upstream's bicycle integration), then as
        the plan in effect moves it; the neighbours moved at their velocity (their prediction then starts there)."""
        scene, ego = perception.scene, perception.scene.ego
        road_angle = perception.tracking.heading - perception.kinematics.heading  # [rad] the road's direction, world axes
        moved, after = predict(EgoKinematics(perception.tracking.speed, perception.tracking.heading), command.acceleration,
                               command.steering, self.model)
        c, s = math.cos(road_angle), math.sin(road_angle)
        course = after.heading + slip_angle(command.steering) - road_angle  # [rad] of the velocity, road axes
        x, y = ego.x + c * moved[0] + s * moved[1], ego.y - s * moved[0] + c * moved[1]
        vx, vy = after.speed * math.cos(course), after.speed * math.sin(course)
        ax, ay = command.acceleration * math.cos(course), command.acceleration * math.sin(course)
        if ahead > 1:  # the periods after this one: as the plan in effect moves the car
            now = (self.executed_periods + 1) * self.period  # [s] the plan in effect's time after this step
            later = now + (ahead - 1) * self.period  # [s] its time where the new plan takes effect
            followed = self.followed(self.executing.result, self.executing.commits)
            reading = sample_trajectory(followed, [now, later])
            x, y = x + float(reading.x[1] - reading.x[0]), y + float(reading.y[1] - reading.y[0])
            vx, vy = vx + float(reading.vx[1] - reading.vx[0]), vy + float(reading.vy[1] - reading.vy[0])
            ax, ay = (float(np.interp(later, followed.t, getattr(followed, name))) for name in ("ax", "ay"))
        horizon = ahead * self.period
        ego = dataclasses.replace(ego, x=x, y=y, vx=vx, vy=vy, ax=ax, ay=ay)
        neighbours = tuple(dataclasses.replace(n, x=n.x + n.vx * horizon, y=n.y + n.vy * horizon) for n in scene.neighbours)
        return dataclasses.replace(scene, ego=ego, neighbours=neighbours)

    def _deliver(self) -> _Call | None:
        """The pending plan, put into effect when its periods have passed at this step; else None."""
        call = self.pending
        if call is None or self.steps - self.started_at < call.delivered_after:
            return None
        self.pending = None
        return self._take_effect(call)

    def _take_effect(self, call: _Call) -> _Call:
        """Track ``call`` from where the car is in it (its delivery less the periods it planned ahead), and carry it to
        the next call, which starts max(``replan_every``, its delivery) periods after ``call`` did and plans
        :meth:`_ahead` of that."""
        self.executing, self.executed_periods = call, call.delivered_after - call.ahead
        if call.periods:
            self.expected = call.periods
        gap = max(self.spec.loop.replan_every, call.delivered_after) + self._ahead() - call.ahead
        self.warm, self.previous = self._carried(call.result, gap * self.period)
        self._carried_frame = call.frame
        return call

    def _carry_into(self, env: Any, perception: Perception) -> None:
        """Put the carried warm start and previous plan in the lateral coordinate of ``perception``'s frame. A frame
        along the next road of the route may measure ``d`` from another line (on racetrack-v0 the car's ``d`` jumps by
        210 m between two pieces), and the old frame's lateral set-points and positions would pull every sample
        towards a place that far away (the consistency cost outweighing the rest): they move by the jump of the car's
        own ``d``. Where the old frame no longer reaches the car they are dropped."""
        old, new = self._carried_frame, perception.frame
        self._carried_frame = new
        if old is None or new is None or (self.warm is None and not _present(self.previous)):
            return
        located = old.locate(np.asarray(env.unwrapped.vehicle.position, dtype=float), near_s=old.ego_s)
        if located is None:
            self.warm = None
            self.previous = PreviousPlan.absent(self.config.basis.num_nodes) if self.carries_plan else None
            return
        shift = np.float32(perception.scene.ego.y - located[1])  # [m]
        if abs(shift) <= FRAME_SHIFT_TOLERANCE:
            return
        lateral = shift * (np.arange(SETPOINT_DIM) >= NUM_SEGMENTS)  # p = (v_1..v_4, y_1..y_4)
        if self.warm is not None:
            self.warm = np.asarray(self.warm) + lateral
        if _present(self.previous):
            self.previous = self.previous._replace(setpoints=np.asarray(self.previous.setpoints) + lateral,
                                                   lateral=np.asarray(self.previous.lateral) + shift)

    def _command(self, result: PlanResult, followed: Any, elapsed: float, tracking, env: Any,
                 perception: Perception | None = None, commits: bool = False) -> tuple[Command, bool]:
        """(the command that tracks ``followed`` (:meth:`followed` of ``result`` in world coordinates) ``elapsed`` [s]
        after it was planned, whether the contact guard replaced it by braking now); ``tracking``: the ego's speed and
        world heading; ``perception``: the world now, read when the configuration guards; ``commits``: ``followed`` is
        an INFEASIBLE plan the call commits to (:meth:`_commits`), tracked without braking now."""
        command = self.spec.loop.command(followed, elapsed, tracking, self.model)
        if self._executes_chosen(result):  # P1: the chosen plan, feasible or not
            return command, False
        if self._brakes_now(result, commits):  # executing the fallback: brake now, not after a ramp
            command = brake_at_least(command, result.fallback_deceleration, self.model, float(env.unwrapped.vehicle.speed))
        guarded = False
        if self.spec.loop.contact_guard and perception is not None:
            command, guarded = guard(command, perception.kinematics, perception.scene, self.model)
        return command, guarded
