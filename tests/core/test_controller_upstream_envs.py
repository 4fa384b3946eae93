"""The controller on the rest of upstream highway-env's envs: u-turn-v0, racetrack-large-v0, lane-keeping-v0 (a road
joined part-way along), exit-v0's destination from the env, and lane-keeping-v0's own steering-only action refused."""

from __future__ import annotations

import numpy as np
import pytest

import driveopt
from driveopt.sim.control import ControlError
from driveopt.sim.lane_graph import road_joins
from driveopt.sim.road_frame import build_frame, ego_frame

CONTINUOUS = {"action": {"type": "ContinuousAction"}}
KINEMATICS = {"observation": {"type": "Kinematics"}}  # u-turn-v0's and lane-keeping-v0's own read upstream's cars


def _drive(env_id: str, steps: int, config: dict) -> tuple[driveopt.Controller, bool, float]:
    """``steps`` policy steps of ``env_id`` through bilevel; (the controller, whether it collided, the mean speed
    [m/s]), asserting that the car stays on the road at every step."""
    env = driveopt.gym_make(env_id, config={**CONTINUOUS, **config})
    env.reset(seed=0)
    ctrl = driveopt.Controller("bilevel", samples=100, verbose=False)
    ctrl.reset(env, seed=0)
    crashed, speeds = False, []
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(ctrl.act(env))
        crashed |= bool(env.unwrapped.vehicle.crashed)
        speeds.append(float(env.unwrapped.vehicle.speed))
        assert env.unwrapped.vehicle.on_road, f"{env_id}: on the road at every step"
        if terminated or truncated:
            break
    assert ctrl.status is not None, "it planned"
    return ctrl, crashed, float(np.mean(speeds))


@pytest.mark.slow  # compiles the planner for another road: about 25 s on two busy cores
def test_u_turn_is_driven_along_the_route_back_that_upstream_plans_for_its_ego():
    ctrl, crashed, _ = _drive("u-turn-v0", 4, KINEMATICS)  # 1 Hz: 4 s along the straight towards the U-turn
    assert ctrl.task.route == ("a", "b", "c", "d") and not crashed
    assert {("b", "c"), ("c", "d")} <= set(ctrl.last.frame.roads), "the frame follows the half circle and the road back"


@pytest.mark.slow  # compiles the planner for another road: about 25 s on two busy cores
def test_racetrack_large_is_driven():
    ctrl, crashed, _ = _drive("racetrack-large-v0", 10, {})  # 5 Hz: 2 s
    assert not crashed and ctrl.task.route is None


def test_lane_keeping_frame_joins_the_sine_road_where_the_approach_road_meets_it():
    """lane-keeping-v0's approach road ("d", "a") ends 135 m along its sine road ("a", "b"), not at its start: the
    frame enters the sine road there, the reference line continuous across the join."""
    env = driveopt.gym_make("lane-keeping-v0", config={**CONTINUOUS, **KINEMATICS})
    env.reset(seed=0)
    network = env.unwrapped.road.network
    [(_, _, at)] = road_joins(network, ("d", "a"), ("a", "b"))
    assert at == pytest.approx(135.0)
    frame, _ = ego_frame(env)
    assert frame.roads == (("c", "d"), ("d", "a"), ("a", "b"))
    sine = frame.pieces[-1]
    assert sine.lo == pytest.approx(135.0) and sine.bands[0].s_from == pytest.approx(frame.pieces[-2].s_start + frame.pieces[-2].hi)
    s_join = sine.s_start + sine.lo
    x, y, *_ = frame.to_world(np.array([s_join - 0.01, s_join + 0.01]), np.zeros(2) + sine.d_shift)
    assert np.hypot(np.diff(x), np.diff(y))[0] < 0.5, "no jump in the reference line at the join"
    assert road_joins(network, ("c", "d"), ("d", "a"))[0][2] == 0.0, "roads that start where others end join at 0"
    corner = np.array([134.18, 0.82])  # outside the corner: beyond the approach road's end, before the join
    backwards = build_frame(network, ("a", "b"), ego_longitudinal=140.0)
    assert backwards.roads[:2] == (("d", "a"), ("a", "b")) and backwards.pieces[1].lo == pytest.approx(135.0)
    for built in (frame, backwards):
        sine = next(piece for piece in built.pieces if piece.lo_margin > 0.0)
        s, _, piece, *_ = built.locate(corner, near_s=sine.s_start + sine.lo)
        assert piece is sine and s == pytest.approx(sine.s_start + 134.18)


def test_racetrack_roads_still_join_at_their_starts():
    """A part-way join is looked for only where no lane starts at a lane's end: the end of racetrack-v0's arc
    ("i", "a") lies 1.2 m along the straight ("a", "b") from one lane's end, but lanes of the straight start at the
    arc's lanes' ends, so the roads join at the start, as before."""
    env = driveopt.gym_make("racetrack-v0", config=CONTINUOUS)
    env.reset(seed=0)
    assert {at for _, _, at in road_joins(env.unwrapped.road.network, ("i", "a"), ("a", "b"))} == {0.0}


@pytest.mark.slow  # compiles the planner for another road: about 20 s (the frame's join and the one-step tracking
# have tests that do not drive: above, and tests/sim/test_sim_control.py)
def test_lane_keeping_is_driven_onto_its_sine_road_without_weaving():
    """One simulation step per action: the car follows its plans' course rather than weaving across the 10 m lane
    (it averaged 5 to 7 m/s when each replan inherited the step's turn of the heading)."""
    ctrl, crashed, speed = _drive("lane-keeping-v0", 60, KINEMATICS)  # 10 Hz: 6 s, past the join 47 m ahead
    assert not crashed and ctrl.task.route is None
    assert ctrl.episode.sim.vehicle.lane_index[:2] == ("a", "b"), "on the sine road"
    assert speed > 10.0


def test_lane_keepings_own_steering_only_action_is_refused_at_reset_in_one_line():
    env = driveopt.gym_make("lane-keeping-v0")
    env.reset(seed=0)
    with pytest.raises(ControlError, match="steering only") as error:
        driveopt.Controller("bilevel", samples=100, verbose=False).reset(env, seed=0)
    assert "\n" not in str(error.value)


def test_exit_destination_is_taken_from_the_env():
    """exit-v0 counts success on its exit: with no route of its own the ego is routed there, as upstream routes
    roundabout-v0's and u-turn-v0's egos; a given route still wins."""
    env = driveopt.gym_make("exit-v0", config=CONTINUOUS)
    env.reset(seed=0)
    ctrl = driveopt.Controller("idm")
    ctrl.reset(env, seed=0)
    assert ctrl.task.route == ("0", "1", "2", "exit")
    frame, _ = ego_frame(env, ctrl.task.route)
    assert ("2", "exit") in frame.roads and ("2", "3") not in frame.roads
    env.reset(seed=0)
    straight = driveopt.Controller("idm", route=["0", "1", "2", "3"])
    straight.reset(env, seed=0)
    assert straight.task.route == ("0", "1", "2", "3")
