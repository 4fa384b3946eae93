"""Receding-horizon closed loop in highway-env: observe, plan, track one action period, replan.

Every policy step (``scenario.policy_frequency``, 10 Hz by default) the simulator state becomes a
``Scene`` and a planning problem, the planner returns a trajectory (the fallback when it reports
infeasible), and the exact inverse of upstream's bicycle model turns the plan's first action
period into a ``ContinuousAction``. The sampling mean is carried to the next call when the planner
warm-starts, and the executed plan when its config weighs ``cost.consistency``. The ``idm``
planner instead hands the ego to highway-env's IDM/MOBIL driver. Everything random derives from
the seed: same seed, same episode.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import jax
import numpy as np

from driveopt.config import PlannerConfig
from driveopt.planner import PlanResult, PlanStatus, plan, previous_plan
from driveopt.planners import PlannerSpec, get_planner
from driveopt.problem import PlanningProblem, Scene, build_problem

from driveopt.sim.control import BicycleModel, brake_at_least, command_from_env
from driveopt.sim.env import make_env, step_env
from driveopt.sim.observation import scene_from_env
from driveopt.sim.road_frame import driving_lanes, vehicle_motion
from driveopt.sim.scenarios import Scenario, get_scenario

SAFETY_FACTOR = 0.9  # plans use at most this fraction of the simulator's acceleration and curvature
RENDER_CONFIG = {"screen_width": 1000, "screen_height": 250, "scaling": 7.0}  # [px], [px], [px/m]



def adapt_to_vehicle(config: PlannerConfig, scenario: Scenario, model: BicycleModel) -> PlannerConfig:
    """Cap the planner's acceleration and curvature bounds at what the simulated car can do.

    Upstream's ego accelerates within ``acceleration_range`` and turns at most with curvature
    2 sin(beta_max) / L, beta_max = arctan(tan(delta_max) / 2).
    """
    a_max = SAFETY_FACTOR * min(abs(scenario.acceleration_range[0]), abs(scenario.acceleration_range[1]))
    beta_max = math.atan(0.5 * math.tan(max(abs(s) for s in scenario.steering_range)))
    kappa_max = SAFETY_FACTOR * 2.0 * math.sin(beta_max) / model.length
    projection = dataclasses.replace(
        config.projection,
        a_max=min(config.projection.a_max, a_max),
        kappa_max=min(config.projection.kappa_max, kappa_max) if config.projection.kappa_max > 0 else kappa_max,
    )
    return dataclasses.replace(config, projection=projection, fallback_deceleration=min(config.fallback_deceleration, a_max))


def plannable_scene(scene: Scene, env: Any) -> Scene:
    """The scene with the ego's velocity along its body heading (its course at zero steering).

    The course of upstream's car is heading + slip angle, and the slip angle follows the steering
    command of the moment; the plan starts from the state the next command acts on.
    """
    sim = env.unwrapped
    reference = driving_lanes(sim.road.network, float(sim.vehicle.position[0]))[0]
    motion = vehicle_motion(sim.vehicle, reference)
    c, s = math.cos(motion.heading), math.sin(motion.heading)
    return dataclasses.replace(scene, ego=dataclasses.replace(scene.ego, vx=motion.speed * c, vy=motion.speed * s))


@dataclass
class Episode:
    """What one closed-loop episode did. Times in seconds unless the name says ms."""

    scenario: str
    planner: str
    seed: int
    collided: bool = False
    off_road: bool = False
    sim_duration: float = 0.0  # [s] simulated time reached
    speeds: list[float] = field(default_factory=list)  # [m/s] ego speed after every step
    lateral: list[float] = field(default_factory=list)  # [m] ego y after every step
    plan_ms: list[float] = field(default_factory=list)  # [ms] wall time of every planning call
    compile_seconds: float = 0.0  # wall time of the warm-up planning call (jit compilation)
    sim_seconds: float = 0.0  # wall time spent in the simulator
    plan_seconds: float = 0.0  # wall time spent planning
    statuses: Counter = field(default_factory=Counter)

    @property
    def mean_speed(self) -> float:
        return float(np.mean(self.speeds)) if self.speeds else 0.0

    def record(self) -> dict[str, Any]:
        """JSON-ready summary (one line of the bench store)."""
        return {
            "collided": self.collided,
            "off_road": self.off_road,
            "mean_speed": self.mean_speed,
            "sim_duration": self.sim_duration,
            "steps": len(self.speeds),
            "plan_ms": [round(v, 2) for v in self.plan_ms],
            "compile_seconds": self.compile_seconds,
            "sim_seconds": self.sim_seconds,
            "plan_seconds": self.plan_seconds,
            "statuses": dict(self.statuses),
        }


StepCallback = Callable[[Any, PlanResult | None, Episode], None]


def _hand_ego_to_idm(env: Any, v_des: float) -> None:
    """Replace the ego by highway-env's IDM/MOBIL vehicle (it ignores the actions it is sent)."""
    from highway_env.vehicle.behavior import IDMVehicle

    sim = env.unwrapped
    ego = sim.vehicle
    lane = sim.road.network.get_closest_lane_index(ego.position, ego.heading)
    driver = IDMVehicle(sim.road, ego.position, ego.heading, ego.speed, target_lane_index=lane, target_speed=v_des)

    sim.road.vehicles[sim.road.vehicles.index(ego)] = driver
    sim.vehicle = driver


def run_episode(
    scenario: Scenario | str,
    planner: PlannerSpec | str,
    seed: int,
    *,
    duration: float | None = None,
    render: bool = False,
    on_step: StepCallback | None = None,
    before_step: Callable[[Any, PlanResult | None], None] | None = None,
    on_plan: Callable[[Scene, PlanningProblem, PlanResult], None] | None = None,
) -> Episode:
    """Drive one episode. ``on_plan(scene, problem, result)`` is called after every planning call
    (optimiser planners only); ``before_step(env, result)`` after planning, before the simulator
    steps (the state the plan was made from: draw videos here); ``on_step(env, result, episode)``
    after every step."""
    scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
    spec = get_planner(planner) if isinstance(planner, str) else planner
    if duration is not None:
        scenario = scenario.replace(duration=float(duration))
    env = make_env(scenario, render_mode="rgb_array" if render else None)
    if render:
        env.unwrapped.config.update(RENDER_CONFIG)
    try:
        env.reset(seed=seed)
        episode = Episode(scenario.name, spec.name, seed)
        model = BicycleModel.from_env(env)
        key = jax.random.PRNGKey(seed)
        if spec.is_optimiser:
            config = adapt_to_vehicle(spec.config, scenario, model)
            prior = spec.prior(scenario.lanes)

            def observe():
                scene = plannable_scene(scene_from_env(env, scenario), env)
                return scene, build_problem(scene, config.basis, ignore_followers=True)

            period = 1.0 / scenario.policy_frequency  # [s] between replans
            carries_plan = config.cost.consistency > 0

            def carried(result):  # (warm start, previous plan) handed to the next call
                previous = previous_plan(result, period) if carries_plan else None
                return (result.mean if spec.warm_start else None), previous

            # Compile outside the timed loop (the first call's trace and the later calls'); results are discarded.
            start = time.perf_counter()
            warmup = plan(observe()[1], config, key=jax.random.fold_in(key, 1), prior=prior)
            if spec.warm_start or carries_plan:
                warm, previous = carried(warmup)
                plan(observe()[1], config, key=jax.random.fold_in(key, 2), prior=prior, warm_start=warm, previous=previous)
            episode.compile_seconds = time.perf_counter() - start
        else:
            _hand_ego_to_idm(env, scenario.v_des)
        warm = previous = None
        idle = np.zeros(2, dtype=np.float32)
        while True:
            result = None
            action = idle
            if spec.is_optimiser:
                scene, problem = observe()
                key, sub = jax.random.split(key)
                start = time.perf_counter()
                result = plan(problem, config, key=sub, prior=prior, warm_start=warm, previous=previous, x_offset=scene.ego.x)
                elapsed = time.perf_counter() - start
                episode.plan_ms.append(1e3 * elapsed)
                episode.plan_seconds += elapsed
                episode.statuses[result.status.name] += 1
                warm, previous = carried(result)
                if on_plan is not None:
                    on_plan(scene, problem, result)
                command = command_from_env(env, result.safe_trajectory, 0.0, model)
                if result.status != PlanStatus.SUCCESS:  # executing the fallback: brake now, not after a ramp
                    command = brake_at_least(command, result.fallback_deceleration, model, float(env.unwrapped.vehicle.speed))
                action = command.action
            if before_step is not None:
                before_step(env, result)
            start = time.perf_counter()
            outcome = step_env(env, action)
            episode.sim_seconds += time.perf_counter() - start
            ego = env.unwrapped.vehicle
            episode.speeds.append(float(ego.speed))
            episode.lateral.append(float(ego.position[1]))
            episode.sim_duration = outcome.time
            episode.collided |= outcome.crashed
            episode.off_road |= outcome.off_road
            if on_step is not None:
                on_step(env, result, episode)
            if outcome.done or outcome.crashed:
                return episode
    finally:
        env.close()


def episode_record(job: Any, options: dict[str, Any]) -> dict[str, Any]:
    """Bench entry point: one episode of ``job`` (scenario, planner, seed, episode) as a record.

    options (all optional): ``duration`` [s], ``samples`` (batch-size override, see
    ``PlannerSpec.with_samples``), ``weights`` (learned prior checkpoint), ``config`` (planner-config
    overrides, nested sections).
    """
    samples = options.get("samples")
    spec = get_planner(job.planner).with_samples(int(samples) if samples else None).with_weights(options.get("weights"))
    spec = spec.with_overrides(**options.get("config", {}))
    return run_episode(job.scenario, spec, job.env_seed, duration=options.get("duration")).record()
