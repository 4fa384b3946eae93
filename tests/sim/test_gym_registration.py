"""driveopt's gymnasium ids: registered by `import driveopt` in either import order without importing gymnasium
itself, the RL env with a TimeLimit of its episode length."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from driveopt import gym_envs


def _run(code: str) -> str:
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_gym_make_after_import_driveopt_in_a_fresh_process():
    out = _run("""
        import sys
        import driveopt
        heavy = sorted(m for m in ("gymnasium", "highway_env", "jax", "numpy") if m in sys.modules)
        print("heavy", heavy)
        import gymnasium
        env = gymnasium.make("driveopt/highway-v0", config={"action": {"type": "ContinuousAction"}, "duration": 2})
        env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        print("stepped", type(env.unwrapped).__name__, info["speed"] > 0)
        print("ids", sorted(i for i in gymnasium.registry if i.startswith("driveopt/")))
    """)
    assert "heavy []" in out, "import driveopt stays light"
    assert "stepped DriveoptHighwayEnv True" in out
    assert f"ids {sorted(gym_envs.SPECS)}" in out


def test_gymnasium_imported_first_works_too():
    out = _run("""
        import gymnasium
        import driveopt
        print(gymnasium.spec("driveopt/merge-v0").entry_point, gymnasium.spec("driveopt/driving-v0").max_episode_steps)
    """)
    assert out.split() == ["driveopt.sim.env:DriveoptMergeEnv", str(gym_envs.RL_EPISODE_STEPS)]


def test_registration_is_idempotent_and_the_hook_leaves_after_firing():
    out = _run("""
        import sys
        import driveopt
        from driveopt import gym_envs
        gym_envs.install(); gym_envs.install()
        hooks = [f for f in sys.meta_path if type(f).__name__ == "_AfterGymnasium"]
        import gymnasium
        gym_envs.register()
        left = [f for f in sys.meta_path if type(f).__name__ == "_AfterGymnasium"]
        print(len(hooks), len(left), sum(i.startswith("driveopt/") for i in gymnasium.registry))
    """)
    assert out.split() == ["1", "0", str(len(gym_envs.SPECS))]


def test_the_rl_env_is_registered_with_its_episode_length():
    gymnasium = pytest.importorskip("gymnasium")
    from driveopt.rl.env import DrivingEnv

    spec = gymnasium.spec("driveopt/driving-v0")
    default = DrivingEnv()
    try:
        steps = round(default.scenario.duration * default.scenario.policy_frequency)
    finally:
        default.close()
    assert spec.max_episode_steps == steps == gym_envs.RL_EPISODE_STEPS
    env = gymnasium.make("driveopt/driving-v0", scenario=default.scenario.replace(vehicles_count=3), disable_env_checker=True)
    try:
        assert isinstance(env, gymnasium.wrappers.TimeLimit) and env.spec.max_episode_steps == steps
        obs, _ = env.reset(seed=0)
        assert obs.shape == env.observation_space.shape
    finally:
        env.close()


def test_road_layouts_scenario_roads_and_env_ids_come_from_one_table():
    from driveopt.sim import env, scenarios

    # The ids registered before the layouts were one table, exactly, and the controlled env after them.
    assert list(gym_envs.SPECS) == ["driveopt/highway-v0", "driveopt/two-way-v0", "driveopt/merge-v0", "driveopt/driving-v0",
                                    "driveopt/controlled-v0"]
    assert scenarios.ROADS == tuple(gym_envs.ROAD_ENVS) == ("highway", "two-way", "merge")
    assert env.ENV_IDS == gym_envs.ROAD_ENV_IDS == {road: f"driveopt/{road}-v0" for road in scenarios.ROADS}
    for road, env_class in gym_envs.ROAD_ENVS.items():
        assert gym_envs.SPECS[env.ENV_IDS[road]] == (f"driveopt.sim.env:{env_class}", None)
        assert issubclass(getattr(env, env_class), env.gym.Env)
    assert {scenarios.get_scenario(name).road for name in scenarios.list_scenarios()} == set(scenarios.ROADS)
