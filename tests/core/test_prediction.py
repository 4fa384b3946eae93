"""The collision ellipse of a neighbour (with the ego's turned-box growth at t = 0) covers every position where the
two cars' boxes overlap, whatever their headings; the growth fades over the first seconds of the plan."""

import math

import numpy as np
import pytest
from conftest import box_corners, boxes_overlap

from driveopt.prediction import (
    EGO_TURN_FADE,
    PathNeighbour,
    box_corners as turned_corners,
    ego_box_growth,
    ellipse_semi_axes,
    minkowski_ellipse,
)
from driveopt.problem import build_problem, ellipse_axes
from driveopt.scene import EgoState, EllipseMargin, Neighbour, ProblemError, Road, Scene


def _axes_now(ego, other, margin):
    a, b = ellipse_semi_axes(ego, other, margin)
    grow_long, grow_lat = ego_box_growth(ego, np.zeros(1))[:, 0]
    return a + grow_long, b + grow_lat


def _overlaps_inside(ego, other_yaw, axes, rng, reach, draws) -> tuple[int, int]:
    """(how many of ``draws`` offsets of a 5 x 2 m car at ``other_yaw`` [rad], uniform within +-``reach`` [m], overlap
    ``ego``'s box, how many of those lie inside the ellipse of semi-axes ``axes`` [m])."""
    a, b = axes
    ego_box = box_corners(0.0, 0.0, ego.yaw, ego.length, ego.width)
    inside = overlapping = 0
    for dx, dy in rng.uniform(-np.asarray(reach), reach, size=(draws, 2)):
        if boxes_overlap(ego_box, box_corners(dx, dy, other_yaw, 5.0, 2.0)):
            overlapping += 1
            inside += (dx / a) ** 2 + (dy / b) ** 2 <= 1.0
    return overlapping, inside


@pytest.mark.parametrize("ego_yaw, other_yaw", [(0.0, 0.0), (0.3, 0.0), (-0.3, 0.1), (0.0, 0.4), (0.5, -0.2)])
def test_overlapping_boxes_lie_inside_the_ellipse(ego_yaw, other_yaw):
    ego = EgoState(x=0.0, y=0.0, vx=3.0, yaw=ego_yaw)
    axes = _axes_now(ego, Neighbour(x=0.0, y=0.0, vx=3.0, yaw=other_yaw), EllipseMargin(0.0, 0.0))
    overlapping, inside = _overlaps_inside(ego, other_yaw, axes, np.random.default_rng(0), (9.0, 5.0), 4000)
    assert overlapping > 100 and inside == overlapping


def _crossing(yaws) -> PathNeighbour:
    """A car standing at the origin whose path turns through ``yaws`` [rad]."""
    yaws = tuple(float(y) for y in np.atleast_1d(yaws))
    times = tuple(float(k) for k in range(len(yaws)))
    return PathNeighbour(x=0.0, y=0.0, yaw=yaws[0], t=times, path_x=(0.0,) * len(yaws), path_y=(0.0,) * len(yaws),
                         path_yaw=yaws)


@pytest.mark.parametrize("ego_yaw", [0.0, 0.3, -0.5])
@pytest.mark.parametrize("other_yaw", [0.2, 0.6, math.pi / 4, 1.2, 2.4])  # along the axes it is the box's ellipse (below)
def test_a_crossing_cars_overlapping_boxes_lie_inside_its_tighter_ellipse(ego_yaw, other_yaw):
    ego = EgoState(x=0.0, y=0.0, vx=3.0, yaw=ego_yaw)
    axes = _axes_now(ego, _crossing(other_yaw), EllipseMargin(0.0, 0.0))
    overlapping, inside = _overlaps_inside(ego, other_yaw, axes, np.random.default_rng(1), (10.0, 8.0), 2000)
    assert overlapping > 50 and inside == overlapping


def test_the_crossing_ellipse_is_the_smallest_axis_aligned_one_and_the_box_ellipse_for_aligned_boxes():
    margin = EllipseMargin(0.0, 0.0)
    ego = EgoState(x=0.0, y=0.0, vx=3.0)
    for yaw in (0.0, math.pi / 2, math.pi):  # boxes along the axes: sqrt(2) x the summed half-sides, as for any car
        box_ellipse = ellipse_semi_axes(ego, Neighbour(x=0.0, y=0.0, yaw=yaw), margin)
        assert ellipse_semi_axes(ego, _crossing(yaw), margin) == pytest.approx(box_ellipse)
    turning = list(np.linspace(0.1, 1.5, 31))  # a car turning through a junction: hundreds of candidate ellipses
    for yaws in ([math.pi / 4], [0.3], [0.7, 0.9, 1.05], [2.0], turning):
        a, b = ellipse_semi_axes(ego, _crossing(yaws), margin)
        points = (turned_corners(5.0, 2.0, np.asarray(yaws))[:, None, :]
                  + np.array([[2.5, 1.0], [2.5, -1.0], [-2.5, 1.0], [-2.5, -1.0]])[None]).reshape(-1, 2)
        assert np.all((points[:, 0] / a) ** 2 + (points[:, 1] / b) ** 2 <= 1.0 + 1e-6)  # contains the sum's corners
        # no smaller one: for each a' on a fine grid, the least b' that contains every corner (independent reference)
        grid = np.linspace(np.abs(points[:, 0]).max() * 1.0001, 20.0, 20000)
        least_b = np.sqrt(np.max(points[None, :, 1] ** 2 / (1.0 - points[None, :, 0] ** 2 / grid[:, None] ** 2), axis=1))
        assert a * b == pytest.approx(np.min(grid * least_b), rel=1e-3)
        box_a, box_b = ellipse_semi_axes(ego, Neighbour(x=0.0, y=0.0, yaw=yaws[0]), margin)
        if len(yaws) < 10:
            assert a * b < (0.75 if yaws == [math.pi / 4] else 0.95) * box_a * box_b  # smaller than the box around it
    assert minkowski_ellipse(2.5, 1.0, turned_corners(5.0, 2.0, np.array([math.pi / 4]))) == pytest.approx((5.594, 4.505), abs=1e-3)


def test_a_turned_ego_reaches_further_into_the_next_lane_for_the_first_second():
    """The ego's box is taken at its body heading (yaw), else at its direction of travel once it moves; the growth
    fades to nothing by EGO_TURN_FADE, and the problem's ellipses carry it node by node."""
    margin = EllipseMargin(0.0, 0.0)
    other = Neighbour(x=5.0, y=4.0, vx=3.0)
    straight = _axes_now(EgoState(x=0.0, y=0.0, vx=3.0), other, margin)
    turned = _axes_now(EgoState(x=0.0, y=0.0, vx=3.0, yaw=0.3), other, margin)
    by_velocity = _axes_now(EgoState(x=0.0, y=0.0, vx=3.0 * math.cos(0.3), vy=3.0 * math.sin(0.3)), other, margin)
    assert straight == pytest.approx(ellipse_semi_axes(EgoState(x=0.0, y=0.0, vx=3.0), other, margin))
    assert turned[1] > straight[1] + 0.5 and by_velocity == pytest.approx(turned)
    # nearly stopped without a yaw: no direction to take, the box points along the road
    assert _axes_now(EgoState(x=0.0, y=0.0, vx=0.1, vy=0.1), other, margin) == pytest.approx(straight)
    ego, neighbour = EgoState(x=0.0, y=4.0, vx=3.0, yaw=-0.3), Neighbour(x=5.0, y=0.0)
    problem = build_problem(Scene(ego=ego, road=Road(num_lanes=4), neighbours=(neighbour,)))
    b = np.asarray(ellipse_axes(problem)[1])[0]
    t = np.linspace(0.0, 5.0, b.shape[0])
    along_road = ellipse_semi_axes(ego, neighbour, EllipseMargin())[1]
    assert b[0] == pytest.approx(along_road + ego_box_growth(ego, np.zeros(1))[1, 0], rel=1e-5)
    assert np.all(np.diff(b) <= 1e-6) and b[t >= EGO_TURN_FADE] == pytest.approx(along_road, rel=1e-5)


def test_with_a_turn_rate_a_plan_that_stands_keeps_the_turned_box_and_one_that_drives_sheds_it():
    """projection.ego_turn_rate > 0: the growth fades with each sample's own distance travelled, not with time. The
    ego stands turned 0.3 rad 3.5 m beside a car: inside the ellipse grown for its turned box, outside the one along
    the road. Standing still for 5 s keeps the box turned (the obstacle rows are violated once the floor has risen);
    driving beside a car of the same speed turns it back within 2 m (feasible). Fading with time, standing still
    counts as turning back."""
    from driveopt.config import ProjectionConfig, QPConfig
    from driveopt.projection import constraint_residuals
    from driveopt.qp import boundary_values, fit_positions, make_model

    model = make_model()
    t = np.asarray(model.t)

    def obstacle_residual(speed, turn_rate):
        ego = EgoState(x=0.0, y=3.5, vx=speed, yaw=-0.3)
        scene = Scene(ego=ego, road=Road(num_lanes=4), neighbours=(Neighbour(x=0.0, y=0.0, vx=speed),),
                      ellipse_margin=EllipseMargin(0.0, 0.0))
        problem = build_problem(scene)
        b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
        coeffs = fit_positions(model, np.float32(speed * t)[None], np.full((1, t.size), 3.5, np.float32), b_x, b_y)
        cfg = ProjectionConfig(ego_turn_rate=turn_rate)
        return float(constraint_residuals(model, problem, coeffs, cfg).obstacle[0])

    assert obstacle_residual(0.0, 0.179) > 0.1
    assert obstacle_residual(5.0, 0.179) < 1e-3
    assert obstacle_residual(0.0, 0.0) < 1e-3 and obstacle_residual(5.0, 0.0) < 1e-3


@pytest.mark.parametrize("neighbour_yaw", [0.0, 0.6])
def test_a_standing_plan_keeps_the_grown_ellipse_of_a_turned_or_straight_neighbour_to_a_percent(neighbour_yaw):
    """With ego_turn_rate the lateral semi-axis of a standing plan is the neighbour's own (wider when it is turned)
    plus the ego's growth now, whatever the other obstacles: 1% outside it is feasible, 1% inside is not."""
    from driveopt.config import ProjectionConfig, QPConfig
    from driveopt.projection import constraint_residuals
    from driveopt.qp import boundary_values, fit_positions, make_model

    model = make_model()
    t = np.asarray(model.t)
    margin = EllipseMargin(0.0, 0.0)
    neighbour = Neighbour(x=0.0, y=0.0, yaw=neighbour_yaw)
    other = Neighbour(x=-40.0, y=8.0)  # a second, narrower obstacle far away
    probe = EgoState(x=0.0, y=0.0, vx=0.0, yaw=0.3)
    semi_axis = ellipse_semi_axes(probe, neighbour, margin)[1] + ego_box_growth(probe, np.zeros(1))[1, 0]

    def obstacle_residual(scale):
        ego = EgoState(x=0.0, y=scale * semi_axis, vx=0.0, yaw=0.3)
        scene = Scene(ego=ego, road=Road(num_lanes=4), neighbours=(neighbour, other), ellipse_margin=margin)
        problem = build_problem(scene)
        b_x, b_y = boundary_values(problem.init_x, problem.init_y, QPConfig())
        coeffs = fit_positions(model, np.zeros((1, t.size), np.float32), np.full((1, t.size), ego.y, np.float32), b_x, b_y)
        return float(constraint_residuals(model, problem, coeffs, ProjectionConfig(ego_turn_rate=0.179)).obstacle[0])

    assert obstacle_residual(1.01) < 1e-4
    assert obstacle_residual(0.99) > 1e-3


def test_a_time_gap_lengthens_the_ellipse_of_lane_following_cars_by_the_gap_at_the_egos_speed():
    """EllipseMargin.time_gap: a lane-following neighbour's longitudinal semi-axis grows by gap x the ego's forward
    speed (none while it reverses), its lateral one and a crossing car's ellipse stay as they are; the problem carries
    the longer ellipse."""
    plain, gapped = EllipseMargin(), EllipseMargin(time_gap=0.5)
    ego, car = EgoState(x=0.0, y=0.0, vx=20.0), Neighbour(x=30.0, y=0.0, vx=15.0)
    a0, b0 = ellipse_semi_axes(ego, car, plain)
    a1, b1 = ellipse_semi_axes(ego, car, gapped)
    assert a1 == pytest.approx(a0 + 10.0) and b1 == b0
    assert ellipse_semi_axes(EgoState(x=0.0, y=0.0, vx=-2.0), car, gapped) == ellipse_semi_axes(
        EgoState(x=0.0, y=0.0, vx=-2.0), car, plain)
    assert ellipse_semi_axes(ego, _crossing(0.8), gapped) == ellipse_semi_axes(ego, _crossing(0.8), plain)
    axes = [np.asarray(ellipse_axes(build_problem(Scene(ego=ego, road=Road(num_lanes=3), neighbours=(car,),
                                                        ellipse_margin=m)))[0])[0] for m in (plain, gapped)]
    assert axes[1] - axes[0] == pytest.approx(np.full_like(axes[0], 10.0), rel=1e-5)


@pytest.mark.parametrize("gap", [-0.1, 11.0, float("nan"), True])
def test_a_time_gap_outside_0_to_10_s_is_refused(gap):
    with pytest.raises(ProblemError, match="time_gap"):
        EllipseMargin(time_gap=gap)
