"""driveopt commonroad on scenarios built here with commonroad-io: a straight three-lane road with a slow car and a goal
in another lane is reached; an on-ramp (a curved ramp lanelet whose successor is an acceleration lane beside a two-lane
main road, the acceleration lane ending 60 m on) with a car on the main road is merged from, behind the car, to a goal on
the main road, without collision or leaving the road; a scenario the frame cannot represent is refused in one line."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("commonroad")
pytest.importorskip("commonroad_dc")
pytest.importorskip("commonroad_route_planner")

from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile  # noqa: E402
from commonroad.common.util import Interval  # noqa: E402
from commonroad.geometry.shape import Circle, Rectangle  # noqa: E402
from commonroad.planning.goal import GoalRegion  # noqa: E402
from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet  # noqa: E402
from commonroad.prediction.prediction import TrajectoryPrediction  # noqa: E402
from commonroad.scenario.lanelet import Lanelet, LaneletNetwork  # noqa: E402
from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType  # noqa: E402
from commonroad.scenario.scenario import Scenario, ScenarioID  # noqa: E402
from commonroad.scenario.state import CustomState, InitialState  # noqa: E402
from commonroad.scenario.trajectory import Trajectory  # noqa: E402

from driveopt.cli import main  # noqa: E402

LANE, LENGTH = 3.5, 200.0  # [m]


def _lanelet(i: int, left: int | None, right: int | None) -> Lanelet:
    x = np.linspace(0.0, LENGTH, 21)
    lo, hi = (i - 1.5) * LANE, (i - 0.5) * LANE  # lanes 0, 1, 2 from the right: centres -3.5, 0, 3.5 m
    return Lanelet(np.stack([x, np.full_like(x, hi)], 1), np.stack([x, np.full_like(x, 0.5 * (lo + hi))], 1),
                   np.stack([x, np.full_like(x, lo)], 1), 100 + i, adjacent_left=left, adjacent_left_same_direction=left and True,
                   adjacent_right=right, adjacent_right_same_direction=right and True)


def write_scenario(path, obstacle_shape=None, start=(20.0, 0.0)) -> None:
    """Three lanes; the ego at 10 m/s in the middle lane; a car at 2 m/s ahead in it; the goal: the left lane at
    x 100-130 m within 12 s."""
    scenario = Scenario(0.1, ScenarioID(country_id="ZAM", map_name="Test", map_id=1))
    network = LaneletNetwork()
    for lanelet in (_lanelet(0, 101, None), _lanelet(1, 102, 100), _lanelet(2, None, 101)):
        network.add_lanelet(lanelet)
    scenario.add_objects(network)
    states = [CustomState(time_step=k, position=np.array([45.0 + 0.2 * k, 0.0]), orientation=0.0, velocity=2.0)
              for k in range(1, 151)]
    shape = obstacle_shape or Rectangle(4.5, 1.8)
    scenario.add_objects(DynamicObstacle(
        scenario.generate_object_id(), ObstacleType.CAR, shape,
        InitialState(time_step=0, position=np.array([45.0, 0.0]), orientation=0.0, velocity=2.0, acceleration=0.0,
                     yaw_rate=0.0, slip_angle=0.0),
        TrajectoryPrediction(Trajectory(1, states), shape)))
    goal = GoalRegion([CustomState(time_step=Interval(0, 120), position=Rectangle(30.0, LANE, np.array([115.0, LANE])))])
    initial = InitialState(time_step=0, position=np.array(start), orientation=0.0, velocity=10.0, acceleration=0.0,
                           yaw_rate=0.0, slip_angle=0.0)
    problems = PlanningProblemSet([PlanningProblem(1, initial, goal)])
    CommonRoadFileWriter(scenario, problems, "test", "", "", set()).write_to_file(str(path), OverwriteExistingFile.ALWAYS)


RAMP_JOIN, RAMP_END, RAMP_DROP = 50.0, 110.0, 12.0  # [m] the ramp joins at x 50, its acceleration lane ends at 110


def _strip(x: np.ndarray, y: np.ndarray, heading: np.ndarray, lanelet_id: int, **links) -> Lanelet:
    """A lanelet of width LANE along the centre line (x, y) with the given headings [rad]."""
    centre = np.stack([x, y], 1)
    normal = 0.5 * LANE * np.stack([-np.sin(heading), np.cos(heading)], 1)
    return Lanelet(centre + normal, centre, centre - normal, lanelet_id, **links)


def _ramp_y(x):  # [m] the ramp's centre: from RAMP_DROP right of the acceleration lane onto it, a half cosine
    return -LANE - RAMP_DROP * 0.5 * (1.0 + np.cos(np.pi * x / RAMP_JOIN))


def _ramp_heading(x):  # [rad]
    return np.arctan(0.5 * RAMP_DROP * np.pi / RAMP_JOIN * np.sin(np.pi * x / RAMP_JOIN))


def write_ramp_scenario(path, car_x: float = 10.0) -> None:
    """An on-ramp as CommonRoad models one: the ramp lanelet 400 (x 0-50, curving from y -15.5 to -3.5 m, curvature at
    most 0.024 1/m) has the acceleration lane 401 (x 50-110, y -3.5 m) as its successor, which is adjacent (same
    direction) to the main road's right lane 301; the main road has two lanes (y 0 and 3.5 m, lanelets 300-302 and
    310-312, split at x 50 and 110, to x 200). The ego at 12 m/s on the ramp at x 5; a car at 12 m/s on the main road's
    right lane at ``car_x``; the goal: that lane at x 115-145 (past the acceleration lane's end) within 12 s."""
    scenario = Scenario(0.1, ScenarioID(country_id="ZAM", map_name="TestRamp", map_id=1))
    network = LaneletNetwork()
    x = np.linspace(0.0, RAMP_JOIN, 26)
    network.add_lanelet(_strip(x, _ramp_y(x), _ramp_heading(x), 400, successor=[401]))
    x = np.linspace(RAMP_JOIN, RAMP_END, 13)
    network.add_lanelet(_strip(x, np.full_like(x, -LANE), np.zeros_like(x), 401, predecessor=[400], adjacent_left=301,
                               adjacent_left_same_direction=True))
    for k, (start, end) in enumerate(((0.0, RAMP_JOIN), (RAMP_JOIN, RAMP_END), (RAMP_END, LENGTH))):
        x = np.linspace(start, end, int(round((end - start) / 5.0)) + 1)
        for lane, right, left in ((300, 401 if k == 1 else None, 310), (310, 300, None)):
            network.add_lanelet(_strip(
                x, np.full_like(x, LANE if lane == 310 else 0.0), np.zeros_like(x), lane + k,
                predecessor=[lane + k - 1] if k else None, successor=[lane + k + 1] if k < 2 else None,
                adjacent_left=left and left + k, adjacent_left_same_direction=left and True,
                adjacent_right=right if lane == 300 else right + k, adjacent_right_same_direction=right and True))
    scenario.add_objects(network)
    shape = Rectangle(4.5, 1.8)
    states = [CustomState(time_step=k, position=np.array([car_x + 1.2 * k, 0.0]), orientation=0.0, velocity=12.0)
              for k in range(1, 151)]
    scenario.add_objects(DynamicObstacle(
        scenario.generate_object_id(), ObstacleType.CAR, shape,
        InitialState(time_step=0, position=np.array([car_x, 0.0]), orientation=0.0, velocity=12.0, acceleration=0.0,
                     yaw_rate=0.0, slip_angle=0.0),
        TrajectoryPrediction(Trajectory(1, states), shape)))
    goal = GoalRegion([CustomState(time_step=Interval(0, 120), position=Rectangle(30.0, LANE, np.array([130.0, 0.0])))])
    initial = InitialState(time_step=0, position=np.array([5.0, float(_ramp_y(5.0))]),
                           orientation=float(_ramp_heading(5.0)), velocity=12.0, acceleration=0.0, yaw_rate=0.0,
                           slip_angle=0.0)
    problems = PlanningProblemSet([PlanningProblem(1, initial, goal)])
    CommonRoadFileWriter(scenario, problems, "test", "", "", set()).write_to_file(str(path), OverwriteExistingFile.ALWAYS)


def _run_bilevel(tmp_path, write, name: str) -> dict:
    """Write one scenario with ``write`` as ``name``.xml, run ``driveopt commonroad`` with bilevel (60 samples) on it
    and return its one record."""
    folder = tmp_path / "scenarios"
    folder.mkdir()
    write(folder / f"{name}.xml")
    assert main(["commonroad", "--scenarios", str(folder), "--planners", "bilevel", "--samples", "60",
                 "--out", str(tmp_path / "out")]) == 0
    records = [json.loads(line) for line in (tmp_path / "out" / "runs.jsonl").read_text().splitlines()]
    assert len(records) == 1 and records[0]["status"] == "success", records
    return records[0]


@pytest.mark.slow  # about 25 s on 2 cores, most of it compiling the planner
def test_the_command_reaches_a_goal_in_another_lane_past_a_slow_car(tmp_path, capsys):
    record = _run_bilevel(tmp_path, write_scenario, "three_lanes")
    assert record["arrival_step"] is not None and not record["collision"]
    assert (tmp_path / "out" / "trajectories" / "three_lanes__bilevel.json").exists()
    # a rerun resumes: nothing left to run, the record kept
    assert main(["commonroad", "--scenarios", str(tmp_path / "scenarios"), "--planners", "bilevel",
                 "--out", str(tmp_path / "out")]) == 0
    assert len((tmp_path / "out" / "runs.jsonl").read_text().splitlines()) == 1


@pytest.mark.slow  # about 25 s on 2 cores, most of it compiling the planner (10 s with JAX's compilation cache warm)
def test_the_command_merges_from_an_on_ramp_behind_a_car_to_a_goal_on_the_main_road(tmp_path):
    record = _run_bilevel(tmp_path, write_ramp_scenario, "on_ramp")
    assert record["goal_reached"] and record["arrival_step"] is not None
    assert not record["collision"] and not record["collision_while_stopped"] and not record["off_road"]
    poses = json.loads((tmp_path / "out" / "trajectories" / "on_ramp__bilevel.json").read_text())
    # it ends in the main road's right lane (centre y 0), having stayed behind the car (x 10 m + 1.2 m per step) past the
    # join, where the car is beside the acceleration lane
    x, y = poses[-1][1], poses[-1][2]
    assert x > 115.0 and abs(y) < 0.5
    assert all(x_ < 10.0 + 1.2 * step for step, x_, *_ in poses if x_ > RAMP_JOIN)


def test_the_world_reads_an_on_ramp_as_its_route_from_the_ramp_onto_the_main_road(tmp_path):
    """The reference path runs along the ramp and its acceleration lane; the road is the ramp alone on the ramp,
    the acceleration lane and both main lanes beside it, and the main lanes alone once the preview reaches the
    acceleration lane's end; the goal is the main road's right lane, a lane left of the reference."""
    from driveopt.commonroad.world import CommonRoadWorld

    write_ramp_scenario(tmp_path / "ramp.xml")
    world = CommonRoadWorld(tmp_path / "ramp.xml")
    assert world.route[:2] == [400, 401] and 301 in world.route
    ego = world.initial_ego()
    assert ego.x == pytest.approx(5.0, abs=0.1) and ego.y == pytest.approx(0.0, abs=0.05)
    on_ramp, beside, ending = world.road(ego.x, 0.0, 12.0), world.road(60.0, 0.0, 12.0), world.road(90.0, 3.5, 12.0)
    assert on_ramp.num_lanes == 1 and on_ramp.first_lane_center == pytest.approx(0.0, abs=0.05)
    assert beside.num_lanes == 3 and beside.first_lane_center == pytest.approx(0.0, abs=0.1)
    assert ending.num_lanes == 2 and ending.first_lane_center == pytest.approx(LANE, abs=0.1)
    assert world.goal.bands[0] == pytest.approx((0.5 * LANE, 1.5 * LANE), abs=0.05)
    (neighbour, _), = world.neighbours(50)  # the car on the main road's right lane at x 70, past the join: a lane left
    assert neighbour.y == pytest.approx(LANE, abs=0.05) and neighbour.vx == pytest.approx(12.0)


def test_an_unsupported_scenario_is_refused_in_one_line(tmp_path):
    from driveopt.commonroad.world import CommonRoadWorld, UnsupportedScenario

    write_scenario(tmp_path / "round.xml", obstacle_shape=Circle(1.0))
    with pytest.raises(UnsupportedScenario, match="is a Circle") as info:
        CommonRoadWorld(tmp_path / "round.xml")
    assert "\n" not in str(info.value)
    write_scenario(tmp_path / "off.xml", start=(20.0, 30.0))
    with pytest.raises(UnsupportedScenario, match="on no lanelet"):
        CommonRoadWorld(tmp_path / "off.xml")


def test_the_world_reads_lanes_goal_and_obstacles(tmp_path):
    from driveopt.commonroad.world import CommonRoadWorld

    write_scenario(tmp_path / "s.xml")
    world = CommonRoadWorld(tmp_path / "s.xml")
    ego = world.initial_ego()
    road = world.road(ego.x, ego.y, ego.speed)
    assert road.num_lanes == 3 and road.lane_width == pytest.approx(LANE, abs=0.1)
    assert world.goal.bands[0] == pytest.approx((0.5 * LANE, 1.5 * LANE), abs=0.05)
    assert world.goal.x == pytest.approx((100.0, 130.0), abs=0.1)
    # the band widens by a lane per 1.5 s of travel at the initial 10 m/s, at least 20 m: 3.5 m per 20 m
    assert world.goal.widen == pytest.approx(LANE / 20.0, rel=0.03)
    far = world.goal.target_band(world.scene(0, ego, 10.0)[0])  # 80 m before the goal: the whole road
    assert far[0] < -0.5 * LANE
    from driveopt.commonroad.cover import cover_pieces
    from driveopt.commonroad.drive import row_count

    assert row_count(world, 100) == cover_pieces()  # one car, in its segments
    (neighbour, track), = world.neighbours(10)
    assert neighbour.vx == pytest.approx(2.0) and track.future(10, np.array([1.0]), world.dt)[0][0] == pytest.approx(
        neighbour.x + 2.0)


def test_a_folder_without_scenarios_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["commonroad", "--scenarios", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("driveopt: error:") and "no CommonRoad .xml" in err and "\n" not in err


def test_the_tracked_car_starts_as_the_planning_problem_and_follows_a_straight_plan(tmp_path):
    """The tracked car at the initial state is the world's initial ego in the frame (straight road, no slip); the
    model is CommonRoad's VW_VANAGON; a constant-speed plan along its lane moves it 1 m per step at 10 m/s."""
    from commonroad_dc.feasibility.vehicle_dynamics import VehicleParameterMapping

    from driveopt.commonroad.execution import car_pose, frame_state, initial_car, step, vehicle_model
    from driveopt.commonroad.world import VEHICLE, CommonRoadWorld

    write_scenario(tmp_path / "s.xml")
    world = CommonRoadWorld(tmp_path / "s.xml")
    params = VehicleParameterMapping[VEHICLE].value
    model = vehicle_model(params, world.dt)
    assert model.length == pytest.approx(params.a + params.b) and model.acceleration_range[1] == params.longitudinal.a_max
    car = initial_car(world.problem.initial_state)
    ego, expected = frame_state(car, world.frame, model, world.length, world.width), world.initial_ego()
    for field in ("x", "y", "vx", "vy", "ax", "ay", "yaw"):
        assert getattr(ego, field) == pytest.approx(getattr(expected, field), abs=1e-9), field
    t = np.linspace(0.0, 15.0, 101)
    for k in range(20):
        plan = SimpleNamespace(t=t, x=ego.x + 10.0 * t, y=np.zeros_like(t), vx=np.full_like(t, 10.0),
                               vy=np.zeros_like(t), ax=np.zeros_like(t), ay=np.zeros_like(t))
        car, deviation = step(car, plan, world.frame, model)
        assert deviation < 1e-6  # [m] from the plan at the step's end
        ego = frame_state(car, world.frame, model, world.length, world.width)
    pose = car_pose(20, car)
    assert (pose.x, pose.y, pose.yaw, pose.speed) == pytest.approx((40.0, 0.0, 0.0, 10.0), abs=1e-6)
