"""The controller in Stable-Baselines3's and gymnasium's terms (docs/rl-guide.md): SB3's evaluate_policy on the
controlled env in a VecEnv (the in-process ControllerPolicy route is in test_controller.py, next to the quickstart
whose compilation it shares), gymnasium's check_env on every registered id, and the one-line refusals."""

from __future__ import annotations

import warnings

import gymnasium
import highway_env  # noqa: F401  registers highway-v0
import numpy as np
import pytest

import driveopt
from driveopt import gym_envs
from driveopt.controller import ControllerError

pytest.importorskip("stable_baselines3")
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402
from stable_baselines3.common.evaluation import evaluate_policy  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv  # noqa: E402

SHORT = {"action": {"type": "ContinuousAction"}, "duration": 3}  # [s] highway-v0 decides once a second: 3 steps
# idm: the route is the planner's, whichever it is; bilevel's compilation is paid once, by tests/core/test_controller.py
# (the quickstart, then this guide's in-process route), and by the slow SubprocVecEnv test
CONTROLLED = {"env": "highway-v0", "config": {"duration": 3}, "planner": "idm"}


def test_evaluate_policy_on_the_controlled_env_in_a_vec_env():
    """The second route: the controller drives inside the env; SB3 sends ignored actions (NULL_POLICY)."""
    vec = make_vec_env("driveopt/controlled-v0", n_envs=1, vec_env_cls=DummyVecEnv, env_kwargs=CONTROLLED)
    rewards, lengths = evaluate_policy(driveopt.NULL_POLICY, vec, n_eval_episodes=2, return_episode_rewards=True)
    assert lengths == [3, 3] and all(np.isfinite(rewards))
    inner = vec.envs[0].unwrapped
    assert isinstance(inner, driveopt.ControllerEnv) and inner.action_space == gymnasium.spaces.Discrete(1)
    vec.reset()
    _, _, _, infos = vec.step(np.array([0]))
    assert infos[0]["driveopt"]["status"] is None, "idm does not plan"
    assert np.shape(infos[0]["driveopt"]["action"]) == (2,)
    vec.close()


@pytest.mark.parametrize("env_id", list(gym_envs.SPECS))
def test_every_registered_id_passes_gymnasiums_check_env(env_id):
    from gymnasium.utils.env_checker import check_env

    kwargs = {"driveopt/driving-v0": {},
              "driveopt/controlled-v0": {**CONTROLLED, "config": {"duration": 2}}}.get(env_id, {"config": {"duration": 2}})
    env = gymnasium.make(env_id, **kwargs)
    assert not (isinstance(env.observation_space, gymnasium.spaces.Box) and env.observation_space.shape == (1,)
                and np.all(env.observation_space.high == 0)), "a real observation, not the simulator's empty slot"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # upstream Kinematics' unbounded Box is a warning, not a failure
        check_env(env.unwrapped)
    env.close()


def test_the_road_envs_by_id_have_rl_spaces_and_driveopts_loop_none():
    from driveopt.sim.env import make_env
    from driveopt.sim.scenarios import get_scenario

    env = gymnasium.make("driveopt/highway-v0")
    assert env.action_space == gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    assert env.observation_space.shape == (5, 5)
    env.close()
    loop = make_env(get_scenario("two-lane-d1.0"))
    assert loop.observation_space.shape == (1,), "driveopt's own loop reads the simulator, not an observation"
    loop.close()


def test_the_policy_and_the_env_refuse_what_they_cannot_drive():
    env = gymnasium.make("highway-v0", config={"duration": 2})  # DiscreteMetaAction
    with pytest.raises(ControllerError, match="ContinuousAction"):
        driveopt.ControllerPolicy(driveopt.Controller("idm"), env)
    continuous = gymnasium.make("highway-v0", config=SHORT)
    with pytest.raises(ControllerError, match="one env, the VecEnv has 2"):
        driveopt.ControllerPolicy(driveopt.Controller("idm"), DummyVecEnv([lambda: gymnasium.make("highway-v0", config=SHORT)] * 2))

    class Remote:  # what a SubprocVecEnv looks like from here: envs in other processes
        num_envs = 1

    with pytest.raises(ControllerError, match="other processes: use driveopt.sb3.ControllerEnv"):
        driveopt.ControllerPolicy(driveopt.Controller("idm"), Remote())
    policy = driveopt.ControllerPolicy(driveopt.Controller("idm"), continuous)
    with pytest.raises(ControllerError, match="batch of 2 observations"):
        policy.predict(np.zeros((2, 5, 5), np.float32))
    with pytest.raises(ControllerError, match="not ContinuousAction"):
        driveopt.ControllerEnv("highway-v0", config={"action": {"type": "DiscreteMetaAction"}}, planner="idm")
    with pytest.raises(ControllerError, match="either a controller or its settings"):
        driveopt.ControllerEnv("highway-v0", driveopt.Controller("idm"), planner="idm")
    with pytest.raises(ControllerError, match="cannot make env 'no-such-v0'"):
        driveopt.ControllerEnv("no-such-v0", planner="idm")
    with pytest.raises(ControllerError, match=r"call reset\(\) before step\(\)"):
        driveopt.ControllerEnv("highway-v0", planner="idm").step(0)
    env.close(), continuous.close()


@pytest.mark.slow
def test_evaluate_policy_on_the_controlled_env_in_subprocesses():
    """SubprocVecEnv, the route ControllerPolicy cannot take: each worker imports driveopt and compiles the planner."""
    kwargs = {**CONTROLLED, "planner": "bilevel", "samples": 100, "verbose": False}
    vec = make_vec_env("driveopt:driveopt/controlled-v0", n_envs=2, vec_env_cls=SubprocVecEnv, env_kwargs=kwargs)
    try:
        rewards, lengths = evaluate_policy(driveopt.NULL_POLICY, vec, n_eval_episodes=4, return_episode_rewards=True)
    finally:
        vec.close()
    assert lengths == [3, 3, 3, 3] and all(np.isfinite(rewards))
