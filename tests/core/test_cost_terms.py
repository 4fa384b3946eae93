"""The cost weighed over the horizon (CostConfig.time_constant) and the speed it asks for (Scene.slowing, slowing_from)."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt import EgoState, Neighbour, PlanStatus, Road, Scene, build_problem, plan
from driveopt.costs import speed_reference, time_weighted_mean


def test_zero_is_the_plain_mean_and_a_later_shortfall_weighs_less():
    t = jnp.linspace(0.0, 15.0, 100)
    values = jax.random.uniform(jax.random.PRNGKey(0), (3, 100))
    assert np.array_equal(time_weighted_mean(values, t, 0.0), jnp.mean(values, axis=-1))
    early, late = jnp.where(t < 5.0, 1.0, 0.0), jnp.where(t > 10.0, 1.0, 0.0)
    assert float(time_weighted_mean(late, t, 3.0)) < 0.05 * float(time_weighted_mean(early, t, 3.0))
    # the weights start at the first node's time, wherever the nodes' clock starts
    assert np.allclose(time_weighted_mean(values, t + 7.0, 3.0), time_weighted_mean(values, t, 3.0), atol=1e-6)


@pytest.fixture(scope="module")
def slow_car_far_ahead() -> Scene:
    """One lane, the ego at its desired 10 m/s, a car 60 m ahead at 6 m/s: a 15 s plan must slow before its end."""
    return Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=Road(num_lanes=1, lane_width=4.0),
                 neighbours=[Neighbour(x=60.0, y=0.0, vx=6.0)], v_des=10.0)


def test_a_discounted_cost_keeps_the_speed_now_and_slows_later(small_config, slow_car_far_ahead):
    problem = build_problem(slow_car_far_ahead, small_config.basis)
    plans = {}
    for tau in (0.0, 3.0):
        config = small_config.replace(cost={"time_constant": tau})
        result = plan(problem, config, key=jax.random.PRNGKey(0))
        assert result.status == PlanStatus.SUCCESS
        traj = result.trajectory
        gap = 60.0 + 6.0 * np.asarray(traj.t) - np.asarray(traj.x)  # [m] centre to centre
        assert gap.min() > 5.0, f"tau {tau}: the plan closes to {gap.min():.1f} m"
        plans[tau] = traj
    first = {tau: float(np.mean(np.asarray(traj.speed)[np.asarray(traj.t) <= 3.0])) for tau, traj in plans.items()}
    assert first[0.0] < 9.6, first  # the plain mean spreads the shortfall over the horizon: it slows from the start
    assert first[3.0] > first[0.0] + 0.2, first  # discounted: it keeps more of its speed now and slows later


def test_the_speed_reference_comes_down_from_the_plans_start_at_most_slowing_from(small_config):
    t = jnp.linspace(0.0, 15.0, 151) + 4.0  # the reference counts from the plan's first node, wherever its clock starts
    speed = jnp.stack([jnp.full_like(t, 30.0), jnp.full_like(t, 26.0)])  # two plans, starting at 30 and 26 m/s
    traj = SimpleNamespace(t=jnp.broadcast_to(t, speed.shape), speed=speed)
    ego = EgoState(x=0.0, y=0.0, vx=30.0)
    for scene in (Scene(ego=ego, v_des=20.0), Scene(ego=ego, v_des=20.0, slowing=1.5, slowing_from=19.0)):
        # nothing above v_des to come down from: v_des itself, exactly
        assert np.all(np.asarray(speed_reference(traj, build_problem(scene, small_config.basis))) == 20.0)
    reference = np.asarray(speed_reference(traj, build_problem(Scene(ego=ego, v_des=20.0, slowing=1.5, slowing_from=28.0),
                                                               small_config.basis)))
    since = np.asarray(t) - 4.0
    assert np.allclose(reference[0], np.maximum(20.0, 28.0 - 1.5 * since))  # at most slowing_from
    assert np.allclose(reference[1], np.maximum(20.0, 26.0 - 1.5 * since))  # from its own start speed below it


def test_a_car_asked_to_slow_gently_slows_at_the_scenes_slowing_not_at_once(small_config):
    speeds = {}
    for slowing_from in (0.0, 30.0):
        scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=30.0), road=Road(num_lanes=1, lane_width=4.0), v_des=20.0,
                      slowing=1.5, slowing_from=slowing_from)
        result = plan(build_problem(scene, small_config.basis), small_config, key=jax.random.PRNGKey(0))
        assert result.status == PlanStatus.SUCCESS
        traj = result.trajectory
        speeds[slowing_from] = float(np.interp(3.0, np.asarray(traj.t), np.asarray(traj.speed)))
        assert abs(float(traj.speed[-1]) - 20.0) < 1.0, f"from {slowing_from}: ends at {float(traj.speed[-1]):.1f} m/s"
    assert speeds[0.0] < 23.0, speeds  # at once: near v_des within 3 s
    assert speeds[30.0] > 24.5, speeds  # 30 - 1.5 x 3 = 25.5 at the slowing rate
