"""The public controller: driveopt's planners driving the user's own highway-env env.

    import gymnasium, highway_env, driveopt
    env = gymnasium.make("highway-v0", config={"action": {"type": "ContinuousAction"}})
    controller = driveopt.Controller("bilevel", samples=250, v_des=20.0)
    env.reset(seed=0)
    controller.reset(env, seed=0)
    action = controller.act(env)                 # (2,) float32 in [-1, 1]: env.step(action)
    controller.last.result.status, controller.last.plan_seconds
    frame = controller.render(env)               # env made with render_mode="rgb_array": the plans and a HUD drawn on

It does what ``driveopt drive`` does, with the same driver (``drive`` and ``bench`` run the registered planners'
drivers, :mod:`driveopt.drivers`): the car's acceleration and steering ranges, its length, the simulation and
policy frequencies and the road come from the env (``env.unwrapped``: its ``ContinuousAction``, its config, its
lane graph); the plans' acceleration and curvature are capped at what the car can do; each plan starts from the
previous call's sampling mean (warm start) and weighs the previous plan; a plan that is not SUCCESS is replaced by
its fallback, braking at once; the contact guard checks commands at crawling speed. Plans are made in a Frenet
frame along the ego's route through the lane graph (:mod:`driveopt.sim.road_frame`: straight, circular and sine
lanes), turned back into world coordinates for tracking; a road the frame cannot represent (crossing traffic,
lanes that are not parallel) raises :class:`~driveopt.sim.road_frame.RoadFrameError` at ``reset`` or at the step
where the route reaches it. ``render(env)`` draws the latest plan in world coordinates (any road) and a heads-up
display on the env's frame (:mod:`driveopt.viz.overlay`); :class:`RenderPlans` wraps an env so that its own
``render()`` does (gymnasium's ``RecordVideo`` records that). Upstream merge-v0, roundabout-v0 and two-way-v0 raise on array actions in their
rewards, already in ``gymnasium.make``, and lane-keeping-v0 in its ``step``: make them with :func:`driveopt.gym_make`
(:mod:`driveopt.sim.rewards`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from typing import Any, Mapping, Sequence

import gymnasium
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.drivers.base import Decision, DriverSpec, check_given_weights, with_samples_and_config
from driveopt.errors import DriveoptError
from driveopt.registry import get_planner
from driveopt.scene import EllipseMargin, ProblemError
from driveopt.sim import step_hook
from driveopt.sim.control import check_frequencies
from driveopt.sim.lane_graph import env_destination_route
from driveopt.sim.perception import Task


DEFAULT_PLAN_FREQUENCY = 5.0  # [Hz] how often an optimiser plans where the env decides less often and its rates allow
_RECOMPILE_NOTICE_S = 2.0  # [s] a later reset's warm-up slower than this compiled anew (said when verbose)
_ANNOUNCED: set[tuple[str, Any]] = set()  # (planner, samples) whose compilation a reset in this process has said


class ControllerError(DriveoptError):
    """The env or the controller's settings cannot be used (not a highway-env env, reset missing, bad values)."""


@dataclasses.dataclass
class _Episode:
    """The env and the episode a controller was reset on, which ``act`` must be given.

    The driver holds what it read at ``reset``: the car's acceleration and steering ranges, the frequencies, the road
    frame, the warm start and the previous plan. On another env its actions would be normalised to the first env's
    ranges, and after ``env.reset`` it would start from the old episode's plan; both would pass silently. An episode is
    told by the objects highway-env makes anew at every ``env.reset`` (its road and its ego vehicle, the latter read
    after the driver may have swapped it, as ``idm`` does) and by the env's clock, which only moves forward within
    an episode."""

    sim: Any  # env.unwrapped
    road: Any
    vehicle: Any
    time: float  # [s] the env's clock at the latest check

    @classmethod
    def of(cls, sim: Any) -> "_Episode":
        return cls(sim, sim.road, sim.vehicle, float(getattr(sim, "time", 0.0)))

    def check(self, env: Any) -> None:
        """ControllerError, saying what to call, unless ``env`` is the env and the episode of ``reset``."""
        sim = getattr(env, "unwrapped", env)
        if sim is not self.sim:
            raise ControllerError(f"act() was given another env ({type(sim).__name__} at {id(sim):#x}) than the one "
                                  "controller.reset(env, seed) read the car, timing and road from: call "
                                  "controller.reset(env, seed) with this env first (one Controller per env to drive several)")
        now = float(getattr(sim, "time", 0.0))
        if sim.road is not self.road or sim.vehicle is not self.vehicle or now < self.time:
            raise ControllerError("the env was reset since controller.reset(env, seed): call controller.reset(env, seed) "
                                  "after every env.reset(), so that the new episode does not start from the old one's plan")
        self.time = now

    def matches(self, env: Any) -> bool:
        """Whether ``env`` is the env and the episode of ``reset`` (:meth:`check` without raising or updating)."""
        sim = getattr(env, "unwrapped", env)
        return (sim is self.sim and sim.road is self.road and sim.vehicle is self.vehicle
                and float(getattr(sim, "time", 0.0)) >= self.time)


class _WithinPeriod:
    """The controller's plans tracked at every simulation step of the env's policy period
    (:mod:`driveopt.sim.step_hook`): highway-env holds an action for ``simulation_frequency // policy_frequency``
    simulation steps, and a steering angle held for upstream's 1 s period misses a plan that turns within it (a
    roundabout's entry). The first simulation step is the returned action's; at each later one the controller plans
    anew where its planning frequency falls on that step (``replan``: the new plan's command for that step), else
    takes the driver's command for that step alone (``within_period``), unless ``env.step`` was given another
    action."""

    def __init__(self, sim: Any, driver: Any, steps_per_period: int, replan: Any) -> None:
        self.sim, self.driver, self.vehicle, self.replan = sim, driver, sim.vehicle, replan
        self.dt = driver.model.simulation_dt  # [s] one simulation step
        self.steps = steps_per_period  # [-] simulation steps per env policy period
        self.steps_per_plan = driver.model.steps_per_action  # [-] simulation steps between two decisions
        self.acted: tuple[int, np.ndarray] | None = None  # (the env's step count at the decision, the action returned)
        self.tracked = 0  # [-] simulation steps whose command this episode replaced

    def on_step(self, vehicle: Any) -> None:
        if vehicle is not self.vehicle or self.acted is None:
            return
        key, action = self.acted
        step = int(self.sim.steps) - key  # which simulation step of the period this is (0: the action's own)
        if not 0 < step < self.steps or not np.array_equal(np.asarray(self.sim.action_type.last_action), action):
            return
        offset = step % self.steps_per_plan  # [simulation steps] since the latest decision
        if offset == 0:
            command = self.replan(int(self.sim.steps))
        else:
            tracked = self.driver.within_period(self.sim, offset * self.dt)
            command = None if tracked is None else tracked.action
        if command is not None:
            vehicle.action = self.sim.action_type.get_action(command)
            self.tracked += 1


def replans_at(hz: float, simulation_hz: float, policy_hz: float) -> bool:
    """Whether planning ``hz`` times a second plans anew within the env's policy period: a multiple (more than one)
    of its policy frequency that divides its simulation frequency, so the plans fall on whole simulation steps."""
    plans, steps = hz / policy_hz, simulation_hz / hz  # [-] plans per policy period, simulation steps per plan
    return round(plans) > 1 and abs(plans - round(plans)) <= 1e-9 and abs(steps - round(steps)) <= 1e-9


def _state_key(env: Any) -> int:
    """The env's simulation step count: which state of the episode a decision was made at."""
    return int(getattr(env.unwrapped, "steps", 0))


def _env_speed_limit(env: Any) -> float:
    """[m/s] the speed limit of the ego's lane."""
    sim = env.unwrapped
    return float(sim.road.network.get_lane(sim.vehicle.lane_index).speed_limit)


class Controller:
    """A registered planner (``driveopt planners``) as a controller of the user's env; see the module docstring.

    ``planner``: a registered name or a :class:`~driveopt.drivers.base.DriverSpec`; ``samples``: samples per sampler
    iteration (default: the planner's own; ``bilevel``: 250, real time on two CPU cores; ``config``'s
    ``sampler.num_samples``, where given, must agree); ``config``: a
    :class:`~driveopt.config.PlannerConfig`, or overrides as nested sections (``{"cost": {"consistency": 1.0}}``);
    ``v_des`` [m/s]: desired speed (default: the speed limit of the ego's lane at ``reset``); ``route``: node names of
    the env's lane graph to follow (e.g. ``["0", "1", "2", "3"]`` drives exit-v0 straight on; default: the ego's own
    route, else the destination the env routes its ego to (intersection-v0's ``destination``, roundabout-v0's and
    exit-v0's exit, u-turn-v0's road back), else straight on); ``weights``: a learned prior's checkpoint (a path that
    is not a file, or weights for a planner without a learned prior, is a WeightsError here);
    ``latency``: ``"sync"`` (default: each ``act`` returns the command of the plan it just made), ``"measured"`` or a
    compute time [ms]: each plan takes effect that many policy periods (rounded up, at least one) after the ``act``
    that started it, and the car keeps tracking the previous plan meanwhile (:mod:`driveopt.drivers.latency`);
    ``track_within_period``: where the env holds each action for several simulation steps (upstream's 1 Hz envs: 15),
    the plan is tracked at every one of them, the first with the returned action (default True; False: the returned
    action is held for the whole period, as the env does for any policy; optimisers only);
    ``plan_frequency`` [Hz]: how often the optimiser plans; a multiple of the env's policy frequency that divides its
    simulation frequency plans anew within the env's period too (upstream's 1 Hz envs simulate at 15 Hz: 3, 5 or 15),
    at the simulation steps it falls on, each plan tracked until the next (needs ``track_within_period``; ``last``
    is the latest decision, within the period or not); the env's own policy frequency plans once per ``act``;
    default :data:`DEFAULT_PLAN_FREQUENCY` (5 Hz) where the env decides less often and its rates allow it (at
    upstream's 1 Hz envs: a plan at the policy step and four within the period), else once per ``act``;
    ``time_gap`` [s]: the headway the plans keep to the cars in the lanes, on top of the collision ellipse (the
    ellipse of a car following its lane is longer by this time at the ego's speed; default 0: the ellipse alone), so
    that a plan does not cut in just ahead of or behind a car whose braking the constant-speed prediction misses;
    ``verbose``: ``reset`` writes one line on stderr when it compiles the planner and how long that took
    (``driveopt: compiling bilevel (250 samples) for highway-v0 ... 9.1 s``: the process's first reset of a planner
    and sample count; a later reset only when it took over 2 s, i.e. compiled anew; False: silent).
    """

    def __init__(self, planner: str | DriverSpec = "bilevel", *, samples: int | None = None,
                 config: PlannerConfig | Mapping[str, Any] | None = None, v_des: float | None = None,
                 route: Sequence[str] | None = None, weights: str | None = None,
                 latency: str | float | None = None, track_within_period: bool = True,
                 plan_frequency: float | None = None, time_gap: float = 0.0, verbose: bool = True) -> None:
        spec = get_planner(planner) if isinstance(planner, str) else planner
        if not isinstance(spec, DriverSpec):
            raise ControllerError(f"planner must be a registered name or a DriverSpec, got {type(planner).__name__}")
        if spec.needs_scenario:
            raise ControllerError(f"planner '{spec.name}' drives only driveopt's scenarios (its policy was trained on "
                                  f"their observation and car): use `driveopt drive --planner {spec.name}`; the "
                                  "controller drives the optimisers and idm")
        if isinstance(config, PlannerConfig):
            if not spec.is_optimiser:
                raise ControllerError(f"planner '{spec.name}' does not plan with the optimiser: it takes no config")
            spec = dataclasses.replace(spec, config=config)
        if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
            raise ControllerError(f"samples must be a positive integer, got {samples!r}")
        overrides = {} if config is None or isinstance(config, PlannerConfig) else dict(config)
        spec = with_samples_and_config(spec, samples, overrides)
        if v_des is not None and not (isinstance(v_des, (int, float)) and math.isfinite(v_des) and 0.0 < v_des <= 60.0):
            raise ControllerError(f"v_des must be a speed in (0, 60] m/s, got {v_des!r}")
        if route is not None and (isinstance(route, str) or not all(isinstance(node, str) for node in route)):
            raise ControllerError(f"route must be a sequence of node names of the env's lane graph, got {route!r}")
        check_given_weights(spec, weights, getattr(spec, "filter_weights", None))
        self.spec = spec.with_weights(weights).with_latency(latency)
        self.v_des = None if v_des is None else float(v_des)
        self.route = None if route is None else tuple(route)
        for name, value in (("track_within_period", track_within_period), ("verbose", verbose)):
            if not isinstance(value, bool):
                raise ControllerError(f"{name} must be True or False, got {value!r}")
        self.track_within_period = track_within_period
        if plan_frequency is not None:
            if isinstance(plan_frequency, bool) or not isinstance(plan_frequency, (int, float)) \
                    or not (math.isfinite(plan_frequency) and plan_frequency > 0):
                raise ControllerError(f"plan_frequency must be a frequency > 0 Hz, got {plan_frequency!r}")
            if not self.spec.is_optimiser:
                raise ControllerError(f"plan_frequency sets how often an optimiser plans; '{spec.name}' does not plan "
                                      "(idm decides at every simulation step already)")
            if not track_within_period:
                raise ControllerError("plan_frequency needs track_within_period=True: the plans made within the env's "
                                      "period are commanded at its simulation steps")
        self.plan_frequency = None if plan_frequency is None else float(plan_frequency)
        try:
            EllipseMargin(time_gap=time_gap)  # the scene's own check of the gap
        except ProblemError as exc:
            raise ControllerError(str(exc)) from None
        if time_gap and not self.spec.is_optimiser:
            raise ControllerError(f"time_gap sets the headway an optimiser's plans keep; '{spec.name}' does not plan "
                                  "(idm keeps its own time gap)")
        self.time_gap = float(time_gap)
        self.verbose = verbose
        self._within: _WithinPeriod | None = None  # the plan tracked between the env's policy steps
        self._decided_at: int | None = None  # _state_key of the state self.last was decided at
        self._ahead: tuple[int, Decision] | None = None  # a decision render() made for a state act() has not acted at
        self.driver: Any = None
        self.task: Task | None = None
        self.last: Decision | None = None  # what the latest act() decided: action, result, scene, timing, frame
        self.planned: Decision | None = None  # the latest decision that planned (act() may follow a plan open-loop)
        self.episode: _Episode | None = None  # the env and episode that reset() bound the controller to

    @property
    def name(self) -> str:
        return self.spec.name

    def reset(self, env: Any, seed: int = 0) -> None:
        """Start an episode on ``env`` (already reset): read the car, the timing and the road, warm the planner up
        (compile; ``compile_seconds``); ``seed`` seeds the planner's sampling. RoadFrameError when the route's road
        cannot be represented. It binds the controller to this env and episode: call it again after every
        ``env.reset`` and for another env (``act`` refuses both otherwise)."""
        sim = getattr(env, "unwrapped", None)
        if getattr(sim, "road", None) is None or getattr(sim, "vehicle", None) is None:
            raise ControllerError("the env must be a highway-env env that has been reset (env.reset(seed=...)) first")
        spaces = getattr(getattr(sim, "observation_space", None), "spaces", None)
        if isinstance(spaces, Mapping) and "desired_goal" in spaces:
            raise ControllerError(f"{type(sim).__name__} is goal-conditioned (a pose to reach, as parking-v0's spot): "
                                  "driveopt plans along lanes in a frame along a route and has no lane to a parking pose")
        if self.route is not None:
            missing = [node for node in self.route if node not in sim.road.network.graph
                       and not any(node in tos for tos in sim.road.network.graph.values())]
            if missing:
                raise ControllerError(f"route nodes {missing} are not in the env's lane graph; its nodes: "
                                      f"{sorted(set(sim.road.network.graph) | {t for tos in sim.road.network.graph.values() for t in tos})}")
        plan_hz = self._plan_frequency(sim)
        v_des = self.v_des if self.v_des is not None else _env_speed_limit(env)
        route = self.route if self.route is not None else env_destination_route(sim)
        self.task = Task(v_des=v_des, name=getattr(getattr(env, "spec", None), "id", None) or type(sim).__name__,
                         route=route, time_gap=self.time_gap)
        self.driver = self.spec.driver()
        samples = getattr(getattr(getattr(self.spec, "config", None), "sampler", None), "num_samples", None)
        first = (self.name, samples) not in _ANNOUNCED  # the process's first reset of this planner and size compiles
        announce = self.verbose and self.spec.is_optimiser and first
        if announce:  # seconds to a minute; later resets reuse the compiled planner
            print(f"driveopt: compiling {self.name}" + (f" ({samples} samples)" if samples else "") + f" for {self.task.name} ...",
                  end=" ", file=sys.stderr, flush=True)
        start = time.perf_counter()
        try:
            if plan_hz is None:
                self.driver.reset(env, self.task, seed)
            else:
                self.driver.reset(env, self.task, seed, policy_frequency=plan_hz)
        finally:
            if announce:
                print(f"{time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)
        seconds = time.perf_counter() - start
        if self.verbose and self.spec.is_optimiser and not first and seconds > _RECOMPILE_NOTICE_S:
            print(f"driveopt: compiled {self.name} anew for {self.task.name} (another road or car): {seconds:.1f} s",
                  file=sys.stderr, flush=True)
        if self.spec.is_optimiser:
            _ANNOUNCED.add((self.name, samples))
        self.last = self.planned = None
        self._decided_at = self._ahead = None
        self.episode = _Episode.of(sim)
        if self._within is not None:
            step_hook.remove(self._within.vehicle)
        self._within = None
        if self.track_within_period and hasattr(self.driver, "within_period"):  # an optimiser: frequencies checked
            period_steps = int(sim.config["simulation_frequency"] // sim.config["policy_frequency"])
            if period_steps > 1:
                self._within = _WithinPeriod(sim, self.driver, period_steps, self._replan)
                step_hook.install(sim.vehicle, self._within)

    def _plan_frequency(self, sim: Any) -> float | None:
        """[Hz] how often the optimiser plans within the env's period, None: a plan per policy step. A given
        ``plan_frequency`` is checked against the env's frequencies; the default plans at
        :data:`DEFAULT_PLAN_FREQUENCY` where that replans within the period, else per policy step."""
        hz = self.plan_frequency
        if hz is None and not (self.spec.is_optimiser and self.track_within_period):
            return None
        simulation_hz, policy_hz = sim.config["simulation_frequency"], sim.config["policy_frequency"]
        check_frequencies(simulation_hz, policy_hz)
        if hz is None:
            return DEFAULT_PLAN_FREQUENCY if replans_at(DEFAULT_PLAN_FREQUENCY, simulation_hz, policy_hz) else None
        if abs(hz / policy_hz - 1.0) <= 1e-9:
            return None
        if not replans_at(hz, simulation_hz, policy_hz):
            raise ControllerError(f"plan_frequency {hz:g} Hz must be a multiple of the env's policy_frequency "
                                  f"({policy_hz:g} Hz) that divides its simulation_frequency ({simulation_hz:g} Hz): "
                                  "plans are made at whole simulation steps, the first at each policy step")
        return hz

    def _replan(self, key: int) -> np.ndarray:
        """The command of a decision made within the env's policy period, at its simulation step ``key``: its plan
        tracked over this simulation step alone, as at the steps that follow (the decision's own action is the
        command held for its whole period, :attr:`last`.action), or that action where the driver tracks none."""
        decision = self._decide(self.episode.sim, key)
        command = self.driver.within_period(self.episode.sim, 0.0)
        return decision.action if command is None else command.action

    @property
    def compile_seconds(self) -> float:
        """[s] wall time of the warm-up planning call in ``reset``."""
        return float(getattr(self.driver, "compile_seconds", 0.0))

    def act(self, env: Any) -> np.ndarray:
        """The (2,) float32 ``ContinuousAction`` (acceleration, steering in [-1, 1]) for the env's current state.
        ControllerError when ``env`` is not the env ``reset`` was given, or was reset since: the controller plans with
        what it read from that env in that episode."""
        if self.driver is None:
            raise ControllerError("call controller.reset(env, seed) after env.reset() before act()")
        self.episode.check(env)
        key = _state_key(env)
        if self._ahead is not None and self._ahead[0] == key:  # render() planned for this state already
            self.last = self._ahead[1]
        else:
            self._decide(env, key)
        self._ahead = None
        action = np.array(self.last.action, dtype=np.float32)  # a new array each call: envs keep it in their info
        if self._within is not None:
            self._within.acted = (key, action.copy())
        return action

    def _decide(self, env: Any, key: int) -> Decision:
        self.last = self.driver.act(env)
        self._decided_at = key
        if self.last.result is not None or self.planned is None:
            self.planned = self.last
        return self.last

    def render(self, env: Any) -> np.ndarray:
        """(H, W, 3) uint8: ``env.render()`` (the env made with ``render_mode="rgb_array"``) with the plan made for
        the env's current state (sampled, elite and followed trajectories in world coordinates) and a heads-up
        display (time [s], speed and desired speed [m/s] with its source, planner, status, planning time [ms]);
        :mod:`driveopt.viz.overlay`.

        The plan drawn is the one for the state on screen: when ``act`` has not yet been called at this state (the
        usual ``act``, ``env.step``, ``render`` loop, or gymnasium's ``RecordVideo`` rendering after each step),
        ``render`` plans now and the next ``act`` at this state returns that decision instead of planning again, so
        the episode is the same with and without rendering. Before ``reset`` for the env's current episode (the
        frame at ``env.reset``) it draws no plan."""
        from driveopt.viz.overlay import render_decision

        decision = None
        if self.driver is not None and self.episode is not None and self.episode.matches(env):
            key = _state_key(env)
            if self._decided_at != key and (self._ahead is None or self._ahead[0] != key):
                self._ahead = (key, self._decide(env, key))
            decision = self.planned
        v_des = self.task.v_des if self.task is not None else self.v_des
        return render_decision(env, decision, planner=self.name, v_des=v_des, v_des_source=self._v_des_source(),
                               config=getattr(self.driver, "config", None))

    def _v_des_source(self) -> str:
        """Where the desired speed comes from, for the HUD."""
        return "Controller(v_des=)" if self.v_des is not None else "lane speed limit"

    @property
    def status(self) -> Any:
        """The latest planning call's :class:`~driveopt.planner.PlanStatus` (None before one, or for drivers that do
        not plan)."""
        result = self.last.result if self.last is not None else None
        return None if result is None else result.status


class RenderPlans(gymnasium.Wrapper):
    """A gymnasium wrapper whose ``render()`` is ``controller.render(env)``: the env's frame with the plan made for
    that frame's state and its heads-up display (``RecordVideo(RenderPlans(env, controller), "videos")`` records
    them; RecordVideo needs moviepy: ``pip install 'driveopt[video]'``). ``controller.render`` plans for a state
    ``act`` has not reached yet and ``act`` then returns that decision, so frame n shows the plan that drives from
    frame n (not the previous step's). Everything else is the wrapped env's."""

    def __init__(self, env: Any, controller: Controller) -> None:
        if not isinstance(controller, Controller):
            raise ControllerError(f"RenderPlans needs a driveopt.Controller, got {type(controller).__name__}")
        super().__init__(env)
        self.controller = controller

    def render(self) -> np.ndarray:
        return self.controller.render(self.env)
