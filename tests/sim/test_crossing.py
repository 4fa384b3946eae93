"""Crossing traffic (driveopt.sim.crossing): a car crossing the route at a right angle, predicted along its own lane,
is an obstacle at the nodes where it is on the route's lanes and not elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

from driveopt.config import BasisConfig
from driveopt.prediction import PathNeighbour
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, Road as PlannerRoad, Scene
from driveopt.sim.crossing import LANE_SHIFT, crossing_neighbour, lane_leaving_neighbour, may_cross, wreck_neighbour
from driveopt.sim.road_frame import build_frame


def _route_frame():
    network = RoadNetwork()
    for k in range(2):  # two lanes along +x, centred at y = 0 and 4 m
        network.add_lane("a", "b", StraightLane([0.0, 4.0 * k], [300.0, 4.0 * k], width=4.0))
    return build_frame(network, ("a", "b"), ego_longitudinal=50.0)


def _crossing_car(speed=10.0):
    network = RoadNetwork()  # a lane along +y through x = 100 m: at right angles to the route
    network.add_lane("c", "d", StraightLane([100.0, -60.0], [100.0, 60.0], width=4.0))
    road = Road(network=network)
    car = IDMVehicle(road, [100.0, -40.0], heading=np.pi / 2, speed=speed, target_lane_index=("c", "d", 0),
                     route=[("c", "d", 0)])
    car.target_speed = speed
    return car


def test_a_right_angle_crossing_is_an_obstacle_at_the_right_nodes_only():
    frame, car = _route_frame(), _crossing_car()
    assert may_cross(car, frame)
    basis = BasisConfig()
    t = np.linspace(0.0, basis.horizon, basis.num_nodes)
    neighbour = crossing_neighbour(car, frame, np.arange(0.0, 15.01, 0.5), ego_x=50.0)
    assert isinstance(neighbour, PathNeighbour)
    scene = Scene(ego=EgoState(x=50.0, y=0.0, vx=10.0), road=PlannerRoad(num_lanes=2, lane_width=4.0),
                  neighbours=(neighbour,), v_des=10.0)
    problem = build_problem(scene, basis)
    ox, oy, b = np.asarray(problem.obstacle_x[0]), np.asarray(problem.obstacle_y[0]), float(problem.obstacle_b[0])
    assert float(problem.obstacle_mask[0]) == 1.0
    on_road = (oy + b > -2.0) & (oy - b < 6.0)  # the ellipse reaches the route's lanes (y from -2 to 6 m)
    crossing = (t > 3.9) & (t < 4.5)  # it is on the lanes from y = -2 to 6 m: 38 to 46 m at 10 m/s
    assert np.all(on_road[crossing]) and np.allclose(ox[crossing], 50.0, atol=1e-3), "where it crosses, 50 m ahead"
    assert not np.any(on_road[(t < 2.5) | (t > 6.0)]), "before and after, nowhere near the lanes"
    assert b > 2.0 * 1.4, "its box across the road is its length: it drives across"


def test_a_car_turning_towards_the_route_from_beyond_the_frames_reach_is_predicted_along_its_path():
    """A car at 60 degrees to the route, 17 m beside its lanes (beyond the frame's lateral reach), turning onto a lane
    that joins the route at 10 degrees: no node of its path is on the frame while it runs steeply, yet its heading now
    would carry the usual prediction straight across the lanes. It is a path neighbour, on the route's lane where
    its path joins it."""
    frame = _route_frame()
    network = RoadNetwork()
    steep, shallow = np.radians(60.0), np.radians(10.0)
    turn = np.array([100.0, -19.0])  # where the steep lane meets the shallow one
    join = np.array([turn[0] + 19.0 / np.tan(shallow), 0.0])  # the shallow lane meets the route's lane y = 0
    network.add_lane("e", "f", StraightLane(turn - 30.0 * np.array([np.cos(steep), np.sin(steep)]), turn, width=4.0))
    network.add_lane("f", "g", StraightLane(turn, join, width=4.0))
    network.add_lane("g", "h", StraightLane(join, join + [200.0, 0.0], width=4.0))
    car = IDMVehicle(Road(network=network), turn - 4.0 * np.array([np.cos(steep), np.sin(steep)]), heading=steep,
                     speed=8.0, target_lane_index=("e", "f", 0), route=[("e", "f", 0), ("f", "g", 0), ("g", "h", 0)])
    neighbour = crossing_neighbour(car, frame, np.arange(0.0, 15.01, 0.5), ego_x=50.0)
    assert isinstance(neighbour, PathNeighbour)
    assert abs(np.degrees(neighbour.path_yaw[0]) - 60.0) < 1e-6 and abs(neighbour.path_y[-1]) < 0.1


def test_a_car_on_the_routes_own_road_is_left_to_the_usual_prediction():
    frame = _route_frame()
    network = frame.pieces[0].lane  # the route's lane; a car along it does not cross
    road = Road(network=RoadNetwork())
    road.network.add_lane("a", "b", network)
    car = IDMVehicle(road, [80.0, 0.0], heading=0.0, speed=10.0, target_lane_index=("a", "b", 0), route=[("a", "b", 0)])
    assert not may_cross(car, frame)
    assert crossing_neighbour(car, frame, np.arange(0.0, 15.01, 0.5), ego_x=50.0) is None
    with pytest.raises(Exception, match="equally long"):
        PathNeighbour(x=0.0, y=0.0, t=(0.0, 1.0), path_x=(0.0,), path_y=(0.0, 0.0), path_yaw=(0.0, 0.0))


def test_a_routed_car_whose_lanes_cross_the_routes_on_its_own_roads_is_predicted_along_them():
    """Two lanes (y = 0 and 4 m) lead into one that continues the upper lane (a roundabout's two ring lanes into its
    exit): a car in the lower lane routed into it moves across the route's lanes, which the usual prediction, holding
    it in its lane, misses. It is a path neighbour that ends in the one lane; a car in the upper lane, and one with no
    route, are left to the usual prediction."""
    network = RoadNetwork()
    for k in range(2):
        network.add_lane("a", "b", StraightLane([0.0, 4.0 * k], [300.0, 4.0 * k], width=4.0))
    network.add_lane("b", "c", StraightLane([300.0, 4.0], [600.0, 4.0], width=4.0))
    frame = build_frame(network, ("a", "b"), [("a", "b", 1), ("b", "c", 0)], ego_longitudinal=250.0)
    road = Road(network=network)
    times = np.arange(0.0, 15.01, 0.5)

    def car(lane: int, route: list | None) -> IDMVehicle:
        return IDMVehicle(road, [280.0, 4.0 * lane], heading=0.0, speed=10.0, target_lane_index=("a", "b", lane),
                          route=route)

    lower = car(0, [("a", "b", 0), ("b", "c", None)])
    assert not may_cross(lower, frame), "its roads are the route's"
    neighbour = lane_leaving_neighbour(lower, frame, times, ego_x=250.0)
    assert isinstance(neighbour, PathNeighbour)
    assert abs(neighbour.path_y[0]) < 1e-6 and abs(neighbour.path_y[-1] - 4.0) < 1e-6
    assert max(neighbour.path_y) - min(neighbour.path_y) > LANE_SHIFT
    assert lane_leaving_neighbour(car(1, [("a", "b", 1), ("b", "c", None)]), frame, times, ego_x=250.0) is None
    assert lane_leaving_neighbour(car(0, None), frame, times, ego_x=250.0) is None


def test_a_path_that_crosses_and_then_runs_beside_the_route_is_bounded_phase_by_phase():
    """A car crossing at a right angle and then oncoming in the lane beside the route: one box for the whole path
    would be as wide as the car is long even while it drives beside the route, reaching into the ego's lane."""
    from driveopt.prediction import path_phases

    t = np.arange(0.0, 10.01, 0.5)
    crossing = t < 3.0
    xs = np.where(crossing, 60.0, 60.0 - 10.0 * (t - 3.0))
    ys = np.where(crossing, 20.0 - 7.0 * t, -4.0)
    yaws = np.where(crossing, -np.pi / 2, np.pi)
    car = PathNeighbour(x=60.0, y=20.0, length=5.0, width=2.0, yaw=-np.pi / 2, t=tuple(t), path_x=tuple(xs),
                        path_y=tuple(ys), path_yaw=tuple(yaws))
    basis = BasisConfig()
    nodes = np.linspace(0.0, basis.horizon, basis.num_nodes)
    phases = path_phases(car, nodes)
    masks = np.array([mask for _, mask in phases])
    assert len(phases) >= 2 and np.all(masks.sum(axis=0) == 1), "every node in exactly one phase"
    crossing_half, oncoming_half = phases[0][0].half_extents, phases[-1][0].half_extents
    # across the road: about half its length while it crosses, about half its width once oncoming (each phase turns
    # by at most 10 deg, so its box leans a little)
    assert crossing_half[1] > 2.4 and oncoming_half[1] < 1.8
    scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=PlannerRoad(num_lanes=1, lane_width=4.0),
                  neighbours=(car,), v_des=10.0)
    problem = build_problem(scene, basis)
    used = int(np.sum(np.asarray(problem.obstacle_mask)))
    assert used == len(phases), "one obstacle slot per phase"
    ox, oy = np.asarray(problem.obstacle_x[:used]), np.asarray(problem.obstacle_y[:used])
    b = np.asarray(problem.obstacle_b[:used])
    late = nodes > 5.0  # oncoming beside the route, 4 m from its centre line
    active = ox[:, late] > -500.0
    assert np.all(active.sum(axis=0) == 1), "one slot holds it at each node, the others are far behind"
    slot = np.nonzero(active[:, 0])[0][0]
    assert np.all(oy[slot, late] == -4.0) and b[slot] < 4.0, "4 m beside the ego's centre line, its ellipse clears it"
    across = np.nonzero(ox[:, np.argmin(np.abs(nodes - 20.0 / 7.0))] > -500.0)[0][0]  # the slot at y = 0 (t = 20/7 s)
    assert b[across] > 4.0, "while it crosses, its ellipse is as wide as the car is long (one box for all would be)"


def test_a_car_going_straight_on_past_the_split_the_route_leaves_by_is_left_to_the_usual_prediction():
    """exit-v0 with the route to the exit: the frame turns into the exit at x = 500 m, a car of lane 3 going straight
    on leaves it there, and beside the turning frame its heading grows away from the frame's. Counted as crossing, its
    box was bounded by those headings (about 20 deg: the ellipse 4.2 m across) and a car beside it in the next lane,
    4 m away, could never pass it; it keeps its lane until it leaves the route, as the usual prediction has it. A car
    that crosses the frame at an angle while on it is still predicted along its path."""
    import driveopt
    from driveopt.sim.road_frame import ego_frame

    env = driveopt.gym_make("exit-v0", config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    sim = env.unwrapped
    sim.vehicle.position[:] = [440.0, 8.0]
    sim.vehicle.lane_index = sim.road.network.get_closest_lane_index(sim.vehicle.position, sim.vehicle.heading)
    frame, me = ego_frame(env, ["0", "1", "2", "exit"])
    straight_on = IDMVehicle(sim.road, [450.0, 12.0], heading=0.0, speed=15.0, target_lane_index=("1", "2", 3),
                             route=[("1", "2", 3), ("2", "3", 3)])
    times = np.arange(0.0, 15.01, 0.5)
    assert may_cross(straight_on, frame), "routed off the frame's roads"
    assert crossing_neighbour(straight_on, frame, times, me.x) is None
    across = IDMVehicle(sim.road, [450.0, 12.0], heading=0.6, speed=15.0, target_lane_index=("1", "2", 3),
                        route=[("2", "3", 3)])  # turned 34 deg across the lanes now, on the frame
    assert isinstance(crossing_neighbour(across, frame, times, me.x), PathNeighbour)


def test_a_turning_cars_phases_lean_at_most_ten_degrees():
    """A car turning steadily from along the route to across it: the phase in which it still runs along the route
    leans at most 10 degrees, so its box reaches at most 2.5 sin 10 + 1 cos 0 = 1.43 m across (1.86 m at 20)."""
    from driveopt.prediction import PHASE_TURN, path_phases

    t = np.arange(0.0, 10.01, 0.5)
    yaws = np.radians(9.0) * t  # 90 degrees in 10 s
    car = PathNeighbour(x=30.0, y=4.0, length=5.0, width=2.0, yaw=0.0, t=tuple(t), path_x=tuple(30.0 + 5.0 * t),
                        path_y=tuple(np.full_like(t, 4.0)), path_yaw=tuple(yaws))
    phases = path_phases(car, t)
    assert phases[0][0].half_extents[1] < 1.45
    for phase, _ in phases:
        assert np.ptp(phase.path_yaw) <= PHASE_TURN + 1e-9


def test_routes_with_a_road_that_names_no_lane_are_predicted_in_the_lane_that_exists():
    """Upstream's prediction picks the lane of a route road that names none by the lane count of the vehicle's own
    road, and fails where a two-lane road leads to a one-lane one (roundabout-v0's exits)."""
    from driveopt.sim.crossing import _along_route

    network = RoadNetwork()
    for k in range(2):
        network.add_lane("a", "b", StraightLane([0.0, 4.0 * k], [50.0, 4.0 * k], width=4.0))
    network.add_lane("b", "c", StraightLane([50.0, 4.0], [50.0, 80.0], width=4.0))  # one lane, turning left
    road = Road(network=network)
    car = IDMVehicle(road, [40.0, 4.0], heading=0.0, speed=10.0, target_lane_index=("a", "b", 1),
                     route=[("a", "b", 1), ("b", "c", None)])
    positions, headings = _along_route(car, np.array([0.0, 0.5, 2.0]))
    np.testing.assert_allclose(positions[0], [40.0, 4.0], atol=1e-9)
    np.testing.assert_allclose(positions[1], [45.0, 4.0], atol=1e-9)
    assert abs(positions[2][0] - 50.0) < 1.0 and 12.0 < positions[2][1] < 17.0  # 12-17 m into the one-lane road
    assert headings[2] == pytest.approx(np.pi / 2, abs=0.2)  # (steered through the joint: see the test below)


def test_a_routed_car_with_the_ego_on_its_lanes_ahead_is_predicted_to_stop_behind_it():
    """highway-env's IDM stops for the car in front on its lane: a car already in a crossing's path is passed by
    nothing, so the crossing car's prediction stops behind it (bumpers YIELD_GAP apart), where holding speed would run
    through it; an ego beside the lanes or behind the car changes nothing."""
    from driveopt.sim.crossing import YIELD_GAP, _along_route

    network = RoadNetwork()
    network.add_lane("a", "b", StraightLane([0.0, 0.0], [50.0, 0.0], width=4.0))
    network.add_lane("b", "c", StraightLane([50.0, 0.0], [50.0, 80.0], width=4.0))
    road = Road(network=network)
    car = IDMVehicle(road, [40.0, 0.0], heading=0.0, speed=10.0, target_lane_index=("a", "b", 0),
                     route=[("a", "b", 0), ("b", "c", None)])
    times = np.arange(0.0, 5.01, 0.5)
    free, _ = _along_route(car, times)
    ego = IDMVehicle(road, [50.0, 20.0], heading=np.pi / 2, speed=0.0)  # 30 m along the car's path, on its next road
    stopped, headings = _along_route(car, times, ego)
    stop_y = 20.0 - 0.5 * (car.LENGTH + ego.LENGTH) - YIELD_GAP
    np.testing.assert_allclose(stopped[times <= 1.0], free[times <= 1.0])  # it keeps its speed until the stop
    np.testing.assert_allclose(stopped[-1], [50.0, stop_y], atol=1e-9)
    assert np.all(stopped[:, 1] <= stop_y + 1e-9) and headings[-1] == pytest.approx(np.pi / 2)
    for elsewhere in ([56.0, 20.0], [30.0, 0.0]):  # beside its lane; behind it
        ego.position = np.array(elsewhere)
        np.testing.assert_allclose(_along_route(car, times, ego)[0], free)
    car.speed = 0.5  # creeping 2.5 m in 5 s: it never reaches the ego 10.5 m ahead, but comes within the gap, so it
    ego.position = np.array([40.0 + 0.5 * (car.LENGTH + ego.LENGTH) + YIELD_GAP + 1.5, 0.0])  # stops 1.5 m on
    crept, _ = _along_route(car, times, ego)
    np.testing.assert_allclose(crept[-1], [41.5, 0.0], atol=1e-9)
    assert np.all(crept[:, 0] <= 41.5 + 1e-9)


@pytest.mark.parametrize("speed", [5.0, 10.0, 16.0])
def test_the_predicted_stop_behind_a_standing_ego_is_where_upstreams_idm_comes_to(speed):
    """highway-env's IDM, closing from 60 m at 5-16 m/s on a car standing on its lane, comes to within 4.2-4.5 m
    (bumpers; it settles at 5 m, its DISTANCE_WANTED less a car's length): the predicted stop, YIELD_GAP behind, is
    no further from the standing car than the real one comes, and less than a metre nearer."""
    from driveopt.sim.crossing import YIELD_GAP

    network = RoadNetwork()
    network.add_lane("a", "b", StraightLane([0.0, 0.0], [500.0, 0.0], width=4.0, speed_limit=20.0))
    road = Road(network=network)
    standing = IDMVehicle(road, [200.0, 0.0], heading=0.0, speed=0.0)
    car = IDMVehicle(road, [140.0, 0.0], heading=0.0, speed=speed, target_speed=speed, target_lane_index=("a", "b", 0),
                     route=[("a", "b", 0)])
    car.enable_lane_change = False
    road.vehicles.extend([standing, car])
    gaps = []
    for _ in range(15 * 30):  # 30 s at upstream's 15 Hz
        car.act()
        car.step(1.0 / 15.0)
        gaps.append(standing.position[0] - car.position[0] - 0.5 * (car.LENGTH + standing.LENGTH))
    assert car.speed == pytest.approx(0.0, abs=0.05) and gaps[-1] == pytest.approx(5.0, abs=0.05)
    assert min(gaps) - 1.0 < YIELD_GAP <= min(gaps)


def _turning_car(x: float, y: float, turn: float) -> PathNeighbour:
    """A car at (x, y) [m] heading across the route (+y), turning by ``turn`` [rad] over 5 s at 5 m/s."""
    t = np.linspace(0.0, 5.0, 11)
    yaw = np.pi / 2 + turn * t / 5.0
    path_x = x + np.concatenate([[0.0], np.cumsum(2.5 * np.cos(yaw[:-1]))])
    path_y = y + np.concatenate([[0.0], np.cumsum(2.5 * np.sin(yaw[:-1]))])
    return PathNeighbour(x=x, y=y, yaw=float(yaw[0]), t=tuple(t), path_x=tuple(path_x), path_y=tuple(path_y),
                         path_yaw=tuple(yaw))


def test_crossing_cars_share_the_slots_by_closest_approach_and_phases_beside_the_road_take_none():
    """Three cars turning through 90 degrees want more than ten phase slots; taking the nearest car's first left the
    farthest out. Every car's phases that reach the road compete by their closest approach to the ego, and a car that
    stays 30 m beside the road takes no slot at all."""
    from driveopt.prediction import ellipse_semi_axes, obstacle_slots, path_phases

    road = PlannerRoad(num_lanes=1, lane_width=4.0)
    cars = (_turning_car(20.0, -8.0, np.pi / 2), _turning_car(35.0, -8.0, np.pi / 2), _turning_car(50.0, -8.0, np.pi / 2))
    beside = _turning_car(40.0, 30.0, 0.3)  # heading away from the road, 30 m beside it
    scene = Scene(ego=EgoState(x=0.0, y=0.0, vx=10.0), road=road, neighbours=cars + (beside,), v_des=10.0)
    basis = BasisConfig()
    nodes = np.linspace(0.0, basis.horizon, basis.num_nodes)
    assert sum(len(path_phases(car, nodes)) for car in cars) > 10
    slots = obstacle_slots(scene, nodes, 10)
    assert all(slot.y != beside.y for slot, _ in slots)
    def approach(slot, on):  # closest approach [m] over the slot's nodes to the ego holding 10 m/s along the road
        x, y = np.interp(nodes, slot.t, slot.path_x), np.interp(nodes, slot.t, slot.path_y)
        return np.min(np.hypot(x - 10.0 * nodes, y)[on])

    def reaches_road(slot, on):  # its ellipse's lateral semi-axis spans its distance from the road at some node
        b = ellipse_semi_axes(scene.ego, slot, scene.ellipse_margin)[1]
        y = np.interp(nodes, slot.t, slot.path_y)[on]
        return np.any(np.abs(y) - 2.0 < b)

    every = sorted(approach(slot, on) for car in cars for slot, on in path_phases(car, nodes) if reaches_road(slot, on))
    assert len(every) > 6 and sorted(approach(slot, on) for slot, on in slots) == pytest.approx(every[:10])
    problem = build_problem(scene, basis)
    assert int(np.sum(np.asarray(problem.obstacle_mask))) == len(slots)
    # without crossing traffic the slots are the relevant neighbours, each whole, as before
    plain = Scene(ego=scene.ego, road=road, neighbours=(Neighbour(x=20.0, y=0.0, vx=5.0),), v_des=10.0)
    assert [(n, nodes_) for n, nodes_ in obstacle_slots(plain, nodes, 10)] == [(plain.neighbours[0], None)]


def test_a_wreck_slides_to_a_stop_along_its_heading_as_highway_env_brakes_it():
    """A crashed car at 10 m/s crossing the route: highway-env brakes it at -speed with its wheels straight, so it
    slides 10 m along its heading and stands; predicted so (not on along its lane at 10 m/s), it is an obstacle on the
    route's lanes only if its slide reaches them, and wherever it stands from then on."""
    frame, car = _route_frame(), _crossing_car()
    times = np.arange(0.0, 15.01, 0.5)
    dt = 0.01  # the slide as the simulator integrates it (its 15 Hz steps, finer here)
    simulated = [np.array(car.position)]
    position, speed = np.array(car.position, dtype=float), 10.0
    for _ in range(int(round(15.0 / dt))):
        position = position + speed * dt * np.array([np.cos(car.heading), np.sin(car.heading)])
        speed -= speed * dt
        simulated.append(position)
    car.crashed = True
    neighbour = wreck_neighbour(car, frame, times, ego_x=50.0)
    assert isinstance(neighbour, PathNeighbour)
    slid = np.asarray(neighbour.path_y) - neighbour.path_y[0]  # across the route: it drives along +y
    expected = np.array([simulated[int(round(t / dt))][1] for t in times]) - simulated[0][1]
    assert np.allclose(slid, expected, atol=0.1)  # Euler at 0.01 s against the exact slide
    assert slid[-1] == pytest.approx(10.0, abs=0.05) and np.allclose(neighbour.path_x, 100.0, atol=1e-6)
    def obstacle_mask(path_neighbour):
        scene = Scene(ego=EgoState(x=50.0, y=0.0, vx=10.0), road=PlannerRoad(num_lanes=2, lane_width=4.0),
                      neighbours=(path_neighbour,), v_des=10.0)
        return float(build_problem(scene, BasisConfig()).obstacle_mask[0])

    assert obstacle_mask(neighbour) == 0.0  # 40 m before the route's lanes, its 10 m slide never reaches them
    car.crashed = False  # the same car, not crashed, crosses the lanes at 4 s: an obstacle
    moving = crossing_neighbour(car, frame, times, ego_x=50.0)
    assert moving.path_y[8] == pytest.approx(0.0, abs=0.5) and obstacle_mask(moving) == 1.0


def _predicted_as_simulated(car):
    """(positions, headings) of ``car()`` (a new ControlledVehicle each call) as highway-env simulates it over 3 s,
    asserted equal (to 1e-6) to the prediction along its route."""
    from driveopt.sim.crossing import STEER_STEP, _along_route

    times = np.arange(46) * STEER_STEP
    predicted, headings = _along_route(car(), times)
    simulated, simulated_headings = [], []
    driven = car()
    for _ in times:
        simulated.append(driven.position.copy())
        simulated_headings.append(driven.heading)
        driven.act()
        driven.step(STEER_STEP)
    np.testing.assert_allclose(predicted, simulated, atol=1e-6)
    np.testing.assert_allclose(headings, simulated_headings, atol=1e-6)
    return simulated, simulated_headings


def test_a_car_whose_lanes_meet_at_an_angle_is_predicted_as_highway_env_steers_it_through_the_joint():
    """At a joint where its lanes meet at an angle (a roundabout's entry: 47-59 degrees at roundabout-v0) a car does
    not turn the whole angle at once: its own lateral controller carries it through. The prediction is highway-env's
    own simulation of the car at its speed, step for step, where the lanes' centres are metres off."""
    from highway_env.vehicle.controller import ControlledVehicle

    from driveopt.sim.crossing import _along_route

    network = RoadNetwork()
    network.add_lane("a", "b", StraightLane([0.0, 0.0], [50.0, 0.0], width=4.0))
    turn = np.radians(60.0)
    network.add_lane("b", "c", StraightLane([50.0, 0.0], [50.0 + 60.0 * np.cos(turn), 60.0 * np.sin(turn)], width=4.0))
    road = Road(network=network)

    def car():
        vehicle = ControlledVehicle(road, [30.0, 0.0], heading=0.0, speed=10.0, target_lane_index=("a", "b", 0),
                                    target_speed=10.0, route=[("a", "b", 0), ("b", "c", 0)])
        return vehicle

    simulated, simulated_headings = _predicted_as_simulated(car)
    lanes = [network.get_lane(("a", "b", 0)), network.get_lane(("b", "c", 0))]
    off_centre = [min(abs(lane.local_coordinates(p)[1]) for lane in lanes) for p in simulated]
    assert max(off_centre) > 1.0, "the lanes' centres would be metres off at the joint"
    # past the steering (1.5 s beyond the joint) it goes on along the lanes from where the steering left it, at its
    # speed: no step back at the hand-over
    later = np.arange(0.0, 6.0, 0.1)
    positions, _ = _along_route(car(), later)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    np.testing.assert_allclose(steps, 10.0 * 0.1, rtol=0.05)


def test_a_car_rolling_backwards_is_predicted_swinging_off_its_lane_as_highway_env_steers_it():
    """Upstream's IDM brakes a car below 0 m/s when the car in front is too close (intersection-v0's traffic yielding
    to the ego); its lateral controller then turns its heading away from its lane, ever faster, and its front swings
    across the lanes beside it. The prediction is highway-env's own simulation of the car at its (negative) speed."""
    from highway_env.vehicle.controller import ControlledVehicle

    network = RoadNetwork()
    network.add_lane("a", "b", StraightLane([0.0, 0.0], [50.0, 0.0], width=4.0))
    road = Road(network=network)

    def car():  # 0.3 m off its lane's centre, 3 degrees off its heading, rolling back at 1.5 m/s
        return ControlledVehicle(road, [30.0, 0.3], heading=0.05, speed=-1.5, target_lane_index=("a", "b", 0),
                                 target_speed=-1.5, route=[("a", "b", 0)])

    simulated, simulated_headings = _predicted_as_simulated(car)
    assert abs(simulated_headings[-1]) > np.radians(20.0), "the heading swings: backing along the lane is far off"
