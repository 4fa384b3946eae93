"""The CommonRoad closed loop's obstacle rows and goal handling without CommonRoad's packages: the segment ellipses
contain the box and are narrower than the single ellipse around it, each row is its own obstacle's recording, and the
previous plan's lateral set-points are held inside the bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from driveopt.commonroad.cover import STRETCH, box_cover, cover_pieces
from driveopt.commonroad.drive import obstacle_rows, previous_within_bounds
from driveopt.commonroad.world import ELLIPSE_MARGIN, Track
from driveopt.config import BasisConfig
from driveopt.planner import PreviousPlan
from driveopt.prediction import ellipse_semi_axes, turned_box_growth
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, Road, Scene

EGO = EgoState(x=0.0, y=0.0, vx=10.0, length=4.569, width=1.844)  # [m] CommonRoad's VW_VANAGON


def _inside(points: np.ndarray, centres: np.ndarray, a: float, b: float) -> np.ndarray:
    """Whether each (x, y) point lies in at least one of the axis-aligned ellipses."""
    x, y = points[:, :1], points[:, 1:]
    return np.any(((x - centres[None, :]) / a) ** 2 + (y / b) ** 2 <= 1.0 + 1e-9, axis=1)


@pytest.mark.parametrize("half_long, half_lat", [(5.285, 2.672), (4.5, 1.82), (0.5, 3.0), (30.0, 1.0)])
@pytest.mark.parametrize("stretch", [1.05, STRETCH, 1.4])
def test_the_cover_contains_the_box_and_is_narrower_than_the_single_ellipse(half_long, half_lat, stretch):
    centres, a, b = box_cover(half_long, half_lat, stretch)
    grid = np.stack(np.meshgrid(np.linspace(-half_long, half_long, 201), np.linspace(-half_lat, half_lat, 41)), -1)
    assert _inside(grid.reshape(-1, 2), centres, a, b).all()  # the box, its edges and corners included
    assert b == pytest.approx(stretch * half_lat) and b < math.sqrt(2.0) * half_lat
    # no farther along the road than the single ellipse, and the ellipses meet at the box's edge, not beyond it
    assert centres[-1] + a <= math.sqrt(2.0) * half_long + 1e-9 and centres[0] - a >= -math.sqrt(2.0) * half_long - 1e-9
    assert not _inside(np.array([[0.0, 1.001 * b]]), centres, a, b).any()


@pytest.mark.parametrize("other", [(6.0, 3.5), (4.8, 2.0), (4.5, 1.8), (12.0, 2.5)])  # [m] obstacles' length x width
def test_the_cover_grown_by_the_egos_turned_box_contains_the_grown_box(other):
    for heading in np.linspace(0.0, 0.5, 11):
        grow_a, grow_b = turned_box_growth(heading, EGO.length, EGO.width)  # added to every semi-axis by the planner
        extra_long, extra_lat = (grow_a, grow_b) / np.sqrt(2.0)  # [m] how much the turned box exceeds the box
        half_long, half_lat = 0.5 * (EGO.length + other[0]), 0.5 * (EGO.width + other[1])
        centres, a, b = box_cover(half_long, half_lat)
        box = np.stack(np.meshgrid(np.linspace(-1.0, 1.0, 201) * (half_long + extra_long),
                                   np.linspace(-1.0, 1.0, 41) * (half_lat + extra_lat)), -1).reshape(-1, 2)
        assert _inside(box, centres, a + grow_a, b + grow_b).all(), heading


def test_the_fewest_pieces_that_reach_no_farther_than_the_single_ellipse():
    assert cover_pieces(1.2) == 2 and cover_pieces(1.1) == 4 and cover_pieces(1.05) == 6 and cover_pieces(1.4) == 2
    centres, _, _ = box_cover(6.0, 2.0, 1.2)
    np.testing.assert_allclose(centres, [-3.0, 3.0])


def test_a_wide_static_obstacle_leaves_room_beside_it_only_with_the_cover():
    # ZAM_Over: a 6 x 3.5 m obstacle centred in a 3.3 m lane, the road's edge 4.925 m from its centre line: the ego's
    # centre may be at most 4.925 - 0.922 = 4.0 m across; the single ellipse reaches 3.78 m with no lateral margin
    obstacle = Neighbour(x=30.0, y=0.0, vx=0.0, length=6.0, width=3.5)
    _, single = ellipse_semi_axes(EGO, obstacle, ELLIPSE_MARGIN)
    _, _, b = box_cover(0.5 * EGO.length + 3.0, 0.5 * EGO.width + 1.75)
    reach = 4.925 - 0.5 * EGO.width
    assert single > reach - 0.3 and b + ELLIPSE_MARGIN.lateral < reach - 0.7


@pytest.mark.parametrize("bad, message", [
    (dict(half_long=0.0, half_lat=1.0), "half_long"), (dict(half_long=1.0, half_lat=math.nan), "half_lat"),
    (dict(half_long=1.0, half_lat=1.0, stretch=1.5), "stretch"), (dict(half_long=1.0, half_lat=1.0, pieces=0), "pieces"),
])
def test_bad_cover_input_is_one_line(bad, message):
    with pytest.raises(ValueError, match=message) as info:
        box_cover(**bad)
    assert "\n" not in str(info.value)


def _track(ident, s, d, vs, vd, length=4.8, width=2.0):
    steps = np.arange(0, 60)
    return Track(ident, length, width, False, steps, s + vs * 0.1 * steps, d + vd * 0.1 * steps, np.full(60, vs),
                 np.full(60, vd), np.zeros(60))


def test_each_row_is_its_own_obstacles_recording_and_cover():
    # a car merging from 14 m off the road (its predicted lateral position is clipped onto the road) and one ahead in
    # the lane: matched by position, the merging car's row was taken for the car ahead
    road = Road(num_lanes=1, lane_width=4.0, first_lane_center=0.0)
    merging, ahead = _track(1, 25.0, -14.0, 8.0, 10.0), _track(2, 28.0, 0.2, 10.0, 0.0)
    present = [(Neighbour(x=t.s[0], y=t.d[0], vx=t.vs[0], vy=t.vd[0], length=t.length, width=t.width), t)
               for t in (merging, ahead)]
    scene = Scene(ego=EGO, road=road, neighbours=tuple(n for n, _ in present), v_des=10.0, ellipse_margin=ELLIPSE_MARGIN)
    basis = BasisConfig()
    times = np.linspace(0.0, basis.horizon, basis.num_nodes)
    problem = build_problem(scene, basis, max_obstacles=6)
    rows = obstacle_rows(problem, scene, present, 0, times, 0.1, 1.0, 1.0)
    mask = np.asarray(rows.obstacle_mask) > 0.5
    assert mask.sum() == 2 * cover_pieces()  # both obstacles, each in its segments
    oy0 = np.asarray(rows.obstacle_y)[mask, 0]
    assert sorted(np.round(oy0, 3)) == pytest.approx(sorted([-14.0, -14.0, 0.2, 0.2]))
    for neighbour, track in present:
        own = np.flatnonzero(mask & (np.abs(np.asarray(rows.obstacle_y)[:, 0] - track.d[0]) < 1e-3))
        s, d = track.future(0, times, 0.1)
        half_long, half_lat = neighbour.half_extents  # the box around the car along its course
        centres, a, b = box_cover(0.5 * EGO.length + half_long, 0.5 * EGO.width + half_lat)
        np.testing.assert_allclose(np.sort(np.asarray(rows.obstacle_x)[own, 5]), s[5] + centres, atol=1e-4)
        np.testing.assert_allclose(np.asarray(rows.obstacle_y)[own], np.broadcast_to(d, (len(own), len(d))), atol=1e-4)
        np.testing.assert_allclose(np.asarray(rows.obstacle_b)[own], b + ELLIPSE_MARGIN.lateral, rtol=1e-6)
        np.testing.assert_allclose(np.asarray(rows.obstacle_a)[own], a + ELLIPSE_MARGIN.longitudinal, rtol=1e-6)
    # without room for the segments the single ellipses stay, each on its own recording
    tight = obstacle_rows(build_problem(scene, basis, max_obstacles=2), scene, present, 0, times, 0.1, 1.0, 1.0)
    assert sorted(np.round(np.asarray(tight.obstacle_y)[:, 0], 3)) == pytest.approx([-14.0, 0.2])
    single = [ellipse_semi_axes(EGO, n, ELLIPSE_MARGIN)[1] for n, _ in present]
    np.testing.assert_allclose(sorted(np.asarray(tight.obstacle_b)), sorted(single), rtol=1e-6)


def test_the_previous_plans_lateral_set_points_are_held_inside_the_bounds():
    road = Road(num_lanes=3, lane_width=3.0, first_lane_center=-3.0)
    problem = build_problem(Scene(ego=EGO, road=road, v_des=10.0))._replace(y_lb=np.float32(-1.0), y_ub=np.float32(1.0))
    previous = PreviousPlan(np.array([9.0, 9.5, 10.0, 10.0, 3.0, 3.0, 0.5, -2.0], np.float32), np.zeros(100, np.float32))
    held = previous_within_bounds(previous, problem)
    np.testing.assert_array_equal(held.setpoints, [9.0, 9.5, 10.0, 10.0, 1.0, 1.0, 0.5, -1.0])
    np.testing.assert_array_equal(held.lateral, previous.lateral)
    np.testing.assert_array_equal(previous.setpoints[4:], [3.0, 3.0, 0.5, -2.0])  # the given plan is left as it was
