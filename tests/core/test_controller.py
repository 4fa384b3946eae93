"""The public controller on upstream highway-env's own envs: the README quickstart, curved roads, refused roads."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import driveopt
from driveopt.controller import DEFAULT_PLAN_FREQUENCY, ControllerError, replans_at
from driveopt.drivers.base import WeightsError
from driveopt.sim.road_frame import RoadFrameError

README = Path(__file__).resolve().parents[2] / "README.md"
CONTINUOUS = {"action": {"type": "ContinuousAction"}}
SHORT_EPISODE = {**CONTINUOUS, "duration": 3}  # [s] highway-v0 decides once a second: 3 steps


def _quickstart() -> str:
    text = README.read_text()
    section = text[text.index("## Quickstart: your own highway-env env"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_quickstart_runs_verbatim_and_stays_on_the_road():
    namespace: dict = {}
    exec(compile(_quickstart(), str(README), "exec"), namespace)
    env, info = namespace["env"], namespace["info"]
    assert not info["crashed"] and env.unwrapped.vehicle.on_road
    assert namespace["controller"].status is not None, "the bilevel planner planned"
    assert env.unwrapped.time >= 10.0 - 1e-9, "the episode ran to its end"


def test_sb3_evaluate_policy_drives_the_controller_in_process():
    """docs/rl-guide.md's in-process route (SB3's evaluate_policy wraps the env in a DummyVecEnv of that object).
    The guide's first route: a policy bound to the env it reads, SB3 wrapping the env in a DummyVecEnv."""
    gymnasium = pytest.importorskip("gymnasium")
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    env = Monitor(driveopt.gym_make("highway-v0", config=SHORT_EPISODE))
    controller = driveopt.Controller("bilevel", samples=100, verbose=False)
    policy = driveopt.ControllerPolicy(controller, env)
    rewards, lengths = evaluate_policy(policy, env, n_eval_episodes=2, return_episode_rewards=True, warn=False)
    assert lengths == [3, 3] and all(np.isfinite(rewards))
    assert controller.status is not None, "it planned"
    assert not controller.episode.matches(env), "the VecEnv reset the env after the last episode"
    action, state = policy.predict(np.zeros(env.observation_space.shape, np.float32))
    assert action.shape == (2,) and state is None, "one observation: one action"
    assert controller.episode.matches(env), "predict noticed the new episode and reset the controller"
    env.close()


def test_frames_draw_the_plan_made_for_their_own_state(capsys, monkeypatch):
    """RecordVideo renders after each env.step: RenderPlans plans for the state on screen, and act() at that state
    returns that very decision, so the episode is the one driven without frames. The first reset says it compiles."""
    import os

    from driveopt import controller as controller_module

    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    monkeypatch.setattr(controller_module, "_ANNOUNCED", set())  # as in a fresh process

    def episode(render: bool, verbose: bool = False) -> tuple[list, list]:
        env = driveopt.gym_make("highway-v0", config=SHORT_EPISODE, render_mode="rgb_array" if render else None)
        env.reset(seed=1)
        ctrl = driveopt.Controller("bilevel", samples=100, verbose=verbose)
        wrapped = driveopt.RenderPlans(env, ctrl)
        drawn = []
        if render:
            wrapped.render()  # the frame at reset: controller.reset not yet called for it, so no plan
            assert ctrl.planned is None
        ctrl.reset(env, seed=1)
        actions, done = [], False
        while not done:
            if render and drawn:
                assert ctrl.act(env) is not None and ctrl.last is drawn[-1], "act returned the frame's decision"
                actions.append(ctrl.last.action)
            else:
                actions.append(ctrl.act(env))
            _, _, terminated, truncated, _ = env.step(np.asarray(actions[-1], np.float32))
            done = terminated or truncated
            if render and not done:
                wrapped.render()
                drawn.append(ctrl.planned)
                assert ctrl.planned.scene.ego.vx == pytest.approx(env.unwrapped.vehicle.speed * np.cos(
                    env.unwrapped.vehicle.heading), abs=0.5), "the frame's plan starts from the state on screen"
        env.close()
        return actions, drawn

    plain, _ = episode(render=False, verbose=True)
    line = capsys.readouterr().err.strip().splitlines()
    assert len(line) == 1 and re.fullmatch(r"driveopt: compiling bilevel \(100 samples\) for highway-v0 \.\.\. \d+\.\d s", line[0])
    recorded, drawn = episode(render=True)
    assert len(drawn) == len(plain) - 1 >= 2
    np.testing.assert_allclose(np.asarray(recorded, float), np.asarray(plain, float), atol=1e-6)
    assert capsys.readouterr().err == "", "verbose=False is silent"


def test_record_video_records_each_frame_with_the_plan_from_the_car(tmp_path, monkeypatch):
    """The recording route the controller's docs give, verbatim: RecordVideo(RenderPlans(env, controller)) writes one
    MP4 with a frame per step (and the reset's), each frame drawing the plan made from the state on screen."""
    import os

    pytest.importorskip("moviepy")
    import imageio.v2 as imageio
    from gymnasium.wrappers import RecordVideo

    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    env = driveopt.gym_make("highway-v0", config=SHORT_EPISODE, render_mode="rgb_array")
    controller = driveopt.Controller("bilevel", samples=100, verbose=False)
    starts = []
    render = controller.render

    def spy(env_):
        frame = render(env_)
        if controller.planned is not None:
            vehicle = env_.unwrapped.vehicle
            starts.append((controller.planned.scene.ego.vx, vehicle.speed * np.cos(vehicle.heading)))
        return frame

    monkeypatch.setattr(controller, "render", spy)
    recorded = RecordVideo(driveopt.RenderPlans(env, controller), str(tmp_path), disable_logger=True)
    recorded.reset(seed=1)
    controller.reset(env, seed=1)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = recorded.step(controller.act(env))
        steps, done = steps + 1, terminated or truncated
    recorded.close()
    (video,) = tmp_path.glob("*.mp4")
    assert imageio.get_reader(video).count_frames() == steps + 1
    assert len(starts) >= steps - 1 >= 2, "the frames after the reset's drew a plan"
    for planned_vx, car_vx in starts:
        assert planned_vx == pytest.approx(car_vx, abs=0.5), "the frame's plan starts from the car on screen"


def test_plan_status_prints_by_name_and_stays_a_number_in_json():
    import json

    from driveopt.planner import PlanStatus

    assert str(PlanStatus.SUCCESS) == f"{PlanStatus.INFEASIBLE:}".replace("INFEASIBLE", "SUCCESS") == "PlanStatus.SUCCESS"
    assert f"{PlanStatus.NUMERICAL_ERROR:>28}" == "  PlanStatus.NUMERICAL_ERROR"
    assert int(PlanStatus.INFEASIBLE) == 1 and json.dumps([PlanStatus.INFEASIBLE]) == "[1]"


def drive(env_id: str, seconds: float, seed: int = 0, make_config: dict | None = None, make_kwargs: dict | None = None,
          **controller) -> dict:
    """Drive ``seconds`` of upstream ``env_id`` (or until the env ends the episode) through the controller; what
    happened."""
    env = driveopt.gym_make(env_id, config={**CONTINUOUS, **(make_config or {})}, **(make_kwargs or {}))
    env.reset(seed=seed)
    ctrl = driveopt.Controller("bilevel", **{"samples": 100, **controller})
    ctrl.reset(env, seed=seed)
    sim = env.unwrapped
    steps = round(seconds * sim.config["policy_frequency"])
    off_road, crashed, statuses, speeds, curvatures = 0, False, [], [], []
    for _ in range(steps):
        action = ctrl.act(env)
        statuses.append(ctrl.status)
        curvatures.append(abs(ctrl.last.scene.road.curvature))
        _, _, terminated, truncated, _ = env.step(action)
        off_road += not sim.vehicle.on_road
        crashed |= bool(sim.vehicle.crashed)  # lane-keeping-v0 gives no info
        speeds.append(float(sim.vehicle.speed))
        if terminated or truncated:
            break
    return {"time": sim.steps / sim.config["simulation_frequency"], "off_road": off_road, "crashed": crashed, "statuses": statuses,
            "mean_speed": float(np.mean(speeds)), "curvatures": curvatures, "env": env, "controller": ctrl}


def test_racetrack_is_driven_for_20_s_without_leaving_the_track():
    run = drive("racetrack-v0", 20.0)
    assert run["time"] >= 20.0 - 1e-9
    assert run["off_road"] == 0 and not run["crashed"]
    assert run["mean_speed"] > 5.0, "it drives round the curves, not crawling"
    assert max(run["curvatures"]) >= 1.0 / 25.0, "the planner saw the track's curves (radii 15 to 25 m)"


UPSTREAM_ROADS = {  # env id -> (gymnasium.make config, make kwargs, controller settings): 20 s of driving each
    "highway-v0": ({"duration": 20}, {}, {}),
    "racetrack-v0": ({}, {}, {}),
    "racetrack-oval-v0": ({}, {}, {}),
    "exit-v0": ({"duration": 20}, {}, {}),
    "merge-v0": ({}, {}, {"v_des": 15.0}),  # upstream ends the episode past x = 370 m: 20 s at 15 m/s
    "two-way-v0": ({"observation": {"type": "Kinematics"}}, {"max_episode_steps": 20}, {}),
    "u-turn-v0": ({"observation": {"type": "Kinematics"}, "duration": 20}, {}, {}),
    "racetrack-large-v0": ({}, {}, {}),
    "lane-keeping-v0": ({"observation": {"type": "Kinematics"}}, {}, {}),
}


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(UPSTREAM_ROADS))
def test_upstream_roads_are_driven_for_20_s_without_leaving_the_road(env_id):
    config, kwargs, settings = UPSTREAM_ROADS[env_id]
    run = drive(env_id, 20.0, make_config=config, make_kwargs=kwargs, **settings)
    assert run["off_road"] == 0 and not run["crashed"], env_id
    assert run["time"] >= 20.0 - 1e-9 or (env_id == "merge-v0" and run["env"].unwrapped.vehicle.position[0] > 370)


def test_exit_route_is_followed_when_asked():
    from driveopt.sim.road_frame import ego_frame

    env = driveopt.gym_make("exit-v0", config=CONTINUOUS)
    env.reset(seed=0)
    assert ("2", "3") in ego_frame(env)[0].roads and ("2", "exit") not in ego_frame(env)[0].roads
    frame, _ = ego_frame(env, route=["0", "1", "2", "exit"])
    assert ("2", "exit") in frame.roads and ("2", "3") not in frame.roads


def test_idm_follows_a_route_with_highway_envs_route_following_or_refuses_it():
    from driveopt.drivers.idm import IDMRouteError

    env = driveopt.gym_make("exit-v0", config=CONTINUOUS)
    env.reset(seed=0)
    driveopt.Controller("idm", route=["0", "1", "2", "exit"]).reset(env, seed=0)
    assert [index[:2] for index in env.unwrapped.vehicle.route] == [("0", "1"), ("1", "2"), ("2", "exit")]
    env.reset(seed=0)
    with pytest.raises(IDMRouteError, match="cannot follow it"):
        driveopt.Controller("idm", route=["2", "exit"]).reset(env, seed=0)


@pytest.mark.slow
def test_exit_route_changes_lanes_before_the_split_and_takes_the_exit():
    """exit-v0's exit leaves from the sixth lane change away: the route's lanes are a goal, reached before the split
    (within the table's 20 s episodes; its seed 0 is the one of 20 that is a lane short)."""
    env = driveopt.gym_make("exit-v0", config={**CONTINUOUS, "duration": 20})
    env.reset(seed=1)
    ctrl = driveopt.Controller("bilevel", samples=250, route=["0", "1", "2", "exit"])
    ctrl.reset(env, seed=1)
    roads, crashed, done = set(), False, False
    while not done:
        _, _, terminated, truncated, info = env.step(ctrl.act(env))
        roads.add(env.unwrapped.vehicle.lane_index[:2])
        crashed |= bool(info["crashed"])
        done = terminated or truncated
    assert not crashed and ("2", "exit") in roads


@pytest.mark.parametrize("env_id, route", [
    pytest.param("intersection-v0", ("o0", "ir0", "il1", "o1"), marks=pytest.mark.slow),  # another compilation: 17 s
    ("roundabout-v0", ("ser", "ses", "se", "ex", "ee", "nx", "nxs"))])
def test_crossings_and_roundabouts_are_driven_toward_the_envs_destination(env_id, route):
    """Crossing traffic is predicted along its own lanes, so the frame follows the route through the junction; the
    destination is the env's (intersection-v0's config, roundabout-v0's exit), as upstream routes its own ego."""
    env = driveopt.gym_make(env_id, config={**CONTINUOUS, "duration": 4})
    env.reset(seed=0)
    ctrl = driveopt.Controller("bilevel", samples=100, verbose=False)
    ctrl.reset(env, seed=0)
    assert ctrl.task.route == route
    done, crashed, steps = False, False, 0
    while not done:
        _, _, terminated, truncated, info = env.step(ctrl.act(env))
        crashed |= bool(info["crashed"])
        assert env.unwrapped.vehicle.on_road, "on the road at every step"
        done, steps = terminated or truncated, steps + 1
    assert not crashed and steps >= 3 and ctrl.status is not None


def test_the_plan_is_tracked_at_every_simulation_step_of_the_envs_period():
    """roundabout-v0 holds an action for 15 simulation steps (1 Hz): tracked at each of them, the car ends every period
    on its plan's course (the exact inverse over each step), where a steering angle held for the period is degrees
    off it as the car turns onto the ring; an action that is not the controller's is held as the env holds any."""
    from driveopt.sim.control import sample_trajectory
    from driveopt.sim.road_frame import slip_angle

    misses = {}
    for within in (True, False):
        env = driveopt.gym_make("roundabout-v0", config={**CONTINUOUS, "duration": 4})
        env.reset(seed=0)
        ctrl = driveopt.Controller("bilevel", samples=100, verbose=False, track_within_period=within,
                                   plan_frequency=1 if within else None)  # one plan per period, as the env decides
        ctrl.reset(env, seed=0)
        period = 1.0 / env.unwrapped.config["policy_frequency"]
        misses[within] = []
        for _ in range(3):
            action = ctrl.act(env)
            planned = sample_trajectory(ctrl.planned.plan_world, ctrl.last.plan_elapsed + period)
            env.step(action)
            car = env.unwrapped.vehicle
            course = car.heading + slip_angle(car.action["steering"])
            miss = (course - np.arctan2(planned.vy, planned.vx) + np.pi) % (2 * np.pi) - np.pi
            misses[within].append(abs(float(miss)))
        if within:
            tracked = ctrl._within.tracked
            assert tracked == 3 * 14, "every simulation step of a period but the action's own"
            env.step(np.zeros(2, np.float32))  # the user's own action: held
            assert ctrl._within.tracked == tracked
    assert max(misses[True]) < 1e-3 < 0.03 < max(misses[False]), misses


@pytest.mark.parametrize("hz", [5, None])  # given, and the default
def test_plan_frequency_replans_within_the_envs_period(hz):
    """At 5 Hz on roundabout-v0 (1 Hz, 15 simulation steps a period) each act is followed by four plans within the
    period (its 3rd, 6th, 9th and 12th simulation steps), each tracked until the next: ``last`` is the period's fifth
    plan, and the car ends the period on that plan's course."""
    from driveopt.sim.control import sample_trajectory
    from driveopt.sim.road_frame import slip_angle

    env = driveopt.gym_make("roundabout-v0", config={**CONTINUOUS, "duration": 4})
    env.reset(seed=0)
    ctrl = driveopt.Controller("bilevel", samples=100, verbose=False, plan_frequency=hz)
    ctrl.reset(env, seed=0)
    for period in range(3):
        env.step(ctrl.act(env))
        assert ctrl.last.plan_index == 5 * period + 4 and ctrl.last.result is not None
        planned = sample_trajectory(ctrl.last.plan_world, ctrl.last.plan_elapsed + 0.2)
        car = env.unwrapped.vehicle
        course = car.heading + slip_angle(car.action["steering"])
        assert abs((course - np.arctan2(planned.vy, planned.vx) + np.pi) % (2 * np.pi) - np.pi) < 1e-3
    assert ctrl._within.tracked == 3 * 14


@pytest.mark.parametrize("simulation_hz, policy_hz, replans", [
    (15, 1, True),  # upstream's 1 Hz envs: a plan at the policy step and four within the period
    (5, 1, True),  # highway-fast-v0: one simulation step per plan
    (15, 5, False),  # the racetracks decide five times a second: once per act
    (10, 2, False),  # 2.5 plans a period: not a whole number
    (20, 10, False),
])
def test_the_default_plan_frequency_replans_only_where_the_env_decides_less_often_and_its_steps_allow(
        simulation_hz, policy_hz, replans):
    assert replans_at(DEFAULT_PLAN_FREQUENCY, simulation_hz, policy_hz) is replans


@pytest.mark.parametrize("hz", [4, 0.5, 30])
def test_a_plan_frequency_the_envs_steps_cannot_hold_is_refused_at_reset(hz):
    env = driveopt.gym_make("highway-v0", config=CONTINUOUS)  # 1 Hz policy, 15 Hz simulation
    env.reset(seed=0)
    with pytest.raises(ControllerError, match="multiple of the env's policy_frequency"):
        driveopt.Controller(samples=100, verbose=False, plan_frequency=hz).reset(env, seed=0)


def test_parking_is_refused_at_reset_in_one_line():
    env = driveopt.gym_make("parking-v0", config=CONTINUOUS)
    env.reset(seed=0)
    with pytest.raises(ControllerError, match="goal-conditioned") as error:
        driveopt.Controller("bilevel", samples=100).reset(env, seed=0)
    assert "\n" not in str(error.value)


def test_roundabout_rewards_accept_array_actions():
    env = driveopt.gym_make("roundabout-v0", config=CONTINUOUS)
    env.reset(seed=0)
    _, reward, *_ = env.step(np.zeros(2, np.float32))
    assert np.isfinite(reward)


@pytest.mark.parametrize("settings, message", [
    ({"v_des": -1.0}, "v_des"), ({"samples": 0}, "samples"), ({"route": "0123"}, "route"),
    ({"planner": "no-such-planner"}, "unknown planner"),
    ({"planner": "dqn"}, "planner 'dqn' drives only driveopt's scenarios"),
    ({"planner": "ppo"}, "use `driveopt drive --planner ppo`"),
    ({"plan_frequency": 0}, "plan_frequency"), ({"plan_frequency": True}, "plan_frequency"),
    ({"planner": "idm", "plan_frequency": 5}, "does not plan"),
    ({"plan_frequency": 5, "track_within_period": False}, "needs track_within_period=True"),
    ({"time_gap": -0.5}, "time_gap"), ({"time_gap": True}, "time_gap"), ({"time_gap": "1"}, "time_gap"),
    ({"planner": "idm", "time_gap": 1.0}, "idm keeps its own time gap"),
    ({"samples": 150, "config": {"sampler": {"num_samples": 250}}}, "150 samples and the config's sampler.num_samples"),
])
def test_bad_settings_raise_one_clear_error(settings, message):
    with pytest.raises(driveopt.DriveoptError, match=message):
        driveopt.Controller(**settings)


def test_samples_and_a_config_that_names_the_same_count_agree():
    controller = driveopt.Controller(samples=250, config={"sampler": {"num_samples": 250}, "cost": {"consistency": 1.0}})
    assert controller.spec.config.sampler.num_samples == 250 and controller.spec.config.cost.consistency == 1.0


def test_act_before_reset_and_unknown_route_nodes_raise():
    env = driveopt.gym_make("highway-v0", config=CONTINUOUS)
    env.reset(seed=0)
    with pytest.raises(ControllerError, match="reset"):
        driveopt.Controller().act(env)
    with pytest.raises(ControllerError, match="not in the env's lane graph"):
        driveopt.Controller(route=["0", "nowhere"]).reset(env, seed=0)


def test_act_is_bound_to_the_env_and_the_episode_of_reset():
    """The controller plans with the car, timing and warm start it read at reset: another env, or the same env reset
    without controller.reset, is refused with what to call, rather than driven with the wrong ranges or plan."""
    config = {**CONTINUOUS, "vehicles_count": 3}
    first, other = driveopt.gym_make("highway-v0", config=config), driveopt.gym_make("highway-v0", config=config)
    first.reset(seed=0)
    other.reset(seed=1)
    controller = driveopt.Controller("idm")
    controller.reset(first, seed=0)
    first.step(controller.act(first))
    controller.act(first.unwrapped)  # the same env, unwrapped: still bound
    with pytest.raises(ControllerError, match=r"another env .* call controller.reset\(env, seed\) with this env first"):
        controller.act(other)
    first.reset(seed=2)
    with pytest.raises(ControllerError, match=r"reset since controller.reset.*after every env.reset\(\)"):
        controller.act(first)
    controller.reset(other, seed=1)
    other.step(controller.act(other))
    with pytest.raises(ControllerError, match="another env"):
        controller.act(first)


@pytest.mark.parametrize("planner, weights, message", [
    ("cvae", "missing.ckpt", "weights file {tmp}/missing.ckpt does not exist"),
    ("cvae", "folder.ckpt", "weights file {tmp}/folder.ckpt is not a regular file"),
    ("bilevel", "given.ckpt", "planner bilevel takes no weights"),
    ("idm", "given.ckpt", "planner idm takes no weights"),
])
def test_weights_that_are_not_a_file_or_not_used_are_refused_at_construction(tmp_path, planner, weights, message):
    """A mistyped checkpoint, or one given to a planner whose prior is not learned, is refused before any episode
    rather than ignored (bilevel would plan with its Gaussian prior as if the weights had been read)."""
    (tmp_path / "given.ckpt").write_bytes(b"weights")
    (tmp_path / "folder.ckpt").mkdir()
    with pytest.raises(WeightsError) as raised:
        driveopt.Controller(planner, weights=str(tmp_path / weights))
    assert str(raised.value).startswith(message.format(tmp=tmp_path))
    with pytest.raises(WeightsError, match=r"filter weights file .*missing.ckpt does not exist"):
        driveopt.Controller("bilevel", config={"safety_filter": {"weights": str(tmp_path / "missing.ckpt")}})
