"""The lane-flow cost term (driveopt.costs.lane_flow): what a plan ending behind a slower car will lose after its horizon."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt import EgoState, Neighbour, PlanStatus, Road, Scene, build_problem, plan
from driveopt.costs import FLOW_REACH, lane_flow

HORIZON = 15.0  # [s] the default basis's


def plans(small_config, *ends):
    """Straight plans at constant speed from (0, 0) to each (x, y) end [m] at the horizon, on the basis's nodes."""
    t = jnp.linspace(0.0, HORIZON, small_config.basis.num_nodes)
    x = jnp.stack([t / HORIZON * end_x for end_x, _ in ends])
    y = jnp.stack([t / HORIZON * end_y for _, end_y in ends])
    return SimpleNamespace(t=jnp.broadcast_to(t, x.shape), x=x, y=y)


def flow(small_config, neighbours, *ends):
    scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=Road(num_lanes=2, lane_width=4.0),
                  neighbours=tuple(neighbours), v_des=10.0)
    return np.asarray(lane_flow(plans(small_config, *ends), build_problem(scene, small_config.basis)))


def test_a_plan_ending_behind_a_slower_car_pays_its_relative_shortfall_and_one_in_a_free_lane_nothing(small_config):
    slow = Neighbour(x=40.0, y=0.0, vx=6.0)  # at 130 m at the horizon
    behind, free_lane, past_it = flow(small_config, [slow], (100.0, 0.0), (100.0, 4.0), (140.0, 0.0))
    assert behind == pytest.approx(((10.0 - 6.0) / 10.0) ** 2, rel=1e-4)
    assert free_lane == 0.0 and past_it == 0.0
    # the slowest of the lane's cars ahead counts; a faster one costs nothing
    slower = Neighbour(x=80.0, y=0.0, vx=4.0)
    assert flow(small_config, [slow, slower], (100.0, 0.0))[0] == pytest.approx(0.36, rel=1e-4)
    assert flow(small_config, [Neighbour(x=40.0, y=0.0, vx=12.0)], (100.0, 0.0))[0] == 0.0


@pytest.mark.parametrize("other", [
    Neighbour(x=300.0, y=4.0, vx=-10.0),  # oncoming
    Neighbour(x=60.0, y=-11.0, vx=6.0, vy=1.0),  # crossing the lanes: in the other lane at the horizon's end
    Neighbour(x=10.0 * HORIZON + FLOW_REACH - 80.0, y=4.0, vx=6.0),  # beyond where a plan at v_des reaches, and then some
    Neighbour(x=-60.0, y=4.0, vx=6.0),  # behind the plan's end at the horizon
    Neighbour(x=120.0, y=4.0, vx=0.0),  # standing
])
def test_cars_not_moving_along_the_lane_ahead_within_reach_are_no_lanes_flow(small_config, other):
    assert flow(small_config, [other], (100.0, 4.0))[0] == 0.0


def test_a_plan_changes_lanes_while_a_slower_car_is_still_far_ahead(small_config):
    """80 m ahead at 6 m/s: a 15 s plan at 10 m/s still ends behind it, so without the term the plan keeps its lane
    and slows only later; with it the plan moves to the free lane now."""
    scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=Road(num_lanes=2, lane_width=4.0),
                  neighbours=(Neighbour(x=80.0, y=0.0, vx=6.0),), v_des=10.0)
    problem = build_problem(scene, small_config.basis)
    ends = {}
    for weight in (0.0, 10.0):
        result = plan(problem, small_config.replace(cost={"lane_flow": weight}), key=jax.random.PRNGKey(0))
        assert result.status == PlanStatus.SUCCESS
        ends[weight] = float(np.asarray(result.trajectory.y)[-1])
    assert abs(ends[0.0]) < 0.5 and abs(ends[10.0] - 4.0) < 0.5, ends
