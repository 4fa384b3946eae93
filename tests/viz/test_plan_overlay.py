"""Plans drawn in world coordinates on a curved road (upstream racetrack-v0 through the public controller), the
heads-up display, the render wrapper, clear errors, and `drive --video` frames with the HUD."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import driveopt  # noqa: E402
import driveopt.viz.video  # noqa: E402
from driveopt.controller import ControllerError  # noqa: E402
from driveopt.viz.overlay import Hud, RenderError, hud_of  # noqa: E402
from driveopt.viz.video import CHOSEN_RGBA, FALLBACK_RGBA, HUD_BG_RGBA, world_to_pixel  # noqa: E402

CONTINUOUS = {"action": {"type": "ContinuousAction"}}


@pytest.fixture(scope="module")
def racetrack():
    """racetrack-v0 (600 x 600 px) after 10 steps of the bilevel controller: its plan runs into the S-bend ahead."""
    env = driveopt.gym_make("racetrack-v0", config=CONTINUOUS, render_mode="rgb_array")
    env.reset(seed=0)
    ctrl = driveopt.Controller("bilevel", samples=100)
    ctrl.reset(env, seed=0)
    for _ in range(10):
        env.step(ctrl.act(env))
    ctrl.act(env)
    yield env, ctrl
    env.close()


def _on_road(sim, xy: np.ndarray) -> np.ndarray:
    network = sim.road.network
    return np.array([network.get_lane(network.get_closest_lane_index(p)).on_lane(p) for p in xy])


def test_the_plan_is_drawn_along_its_world_positions_on_a_curved_road(racetrack):
    env, ctrl = racetrack
    plain = env.render()
    out = ctrl.render(env)
    assert out.shape == plain.shape == (600, 600, 3) and out.dtype == np.uint8
    world = ctrl.planned.plan_world
    xy = np.stack([world.x, world.y], axis=-1)
    heading = np.unwrap(np.arctan2(np.diff(world.y), np.diff(world.x)))
    assert np.ptp(heading) > np.radians(45.0), "the plan turns with the track"
    assert _on_road(env.unwrapped, xy).all(), "the plan's world positions lie on the track"
    # in the road frame the same plan is somewhere else: drawing (s, d) as world points would miss the track
    result = ctrl.planned.result
    sd = np.stack([result.trajectory.x, result.trajectory.y], axis=-1)
    assert np.max(np.hypot(*(sd - xy).T)) > 10.0
    pixels = np.round(world_to_pixel(env, xy)).astype(int)
    inside = (pixels >= 40).all(axis=1) & (pixels < 560).all(axis=1)  # off the HUD and the legend
    assert inside.sum() >= 20, "most of the plan is in view"
    colour = CHOSEN_RGBA[:3] if ctrl.status.name == "SUCCESS" else FALLBACK_RGBA[:3]
    drawn = [tuple(out[py, px]) == colour for px, py in pixels[inside]]
    assert np.mean(drawn) > 0.9, "the followed plan is drawn through its world positions"
    assert np.any(out[pixels[inside, 1], pixels[inside, 0]] != plain[pixels[inside, 1], pixels[inside, 0]])
    # the samples and elites are drawn too: more pixels change than the chosen line's
    changed = np.any(out != plain, axis=-1)
    assert changed[40:560, 40:560].sum() > 4 * len(drawn) * 4


def test_the_hud_shows_time_speeds_planner_status_and_planning_time(racetrack):
    env, ctrl = racetrack
    plain, out = env.render(), ctrl.render(env)
    box = out[4:26, 4:150].astype(int)
    assert np.any(box != plain[4:26, 4:150]), "the HUD region is drawn"
    assert (np.abs(box - HUD_BG_RGBA[:3]) < 60).all(axis=-1).mean() > 0.5, "on a light box"
    assert (box.sum(axis=-1) < 150).any(), "with dark text"
    hud = hud_of(env, ctrl.planned, ctrl.name, ctrl.task.v_des, "lane speed limit")
    assert hud.time == pytest.approx(10 / env.unwrapped.config["policy_frequency"]) and hud.speed == pytest.approx(env.unwrapped.vehicle.speed)
    assert hud.planner == "bilevel" and hud.status.startswith(ctrl.status.name)
    assert hud.plan_ms == pytest.approx(1e3 * ctrl.planned.plan_seconds)
    text = "\n".join(hud.lines())
    assert hud.v_des <= ctrl.task.v_des and hud.v_des == pytest.approx(ctrl.planned.scene.v_des, abs=0.05)
    source = "lane speed limit" if hud.v_des == ctrl.task.v_des else f"curve ahead (lane speed limit: {ctrl.task.v_des:.1f})"
    for needle in (f"t {hud.time:5.1f} s", f"desired {hud.v_des:.1f} from {source}", "bilevel: ", " ms"):
        assert needle in text
    assert "plan -" in "\n".join(Hud(0.0, 0.0, None, "idm", "-", None).lines())


def test_the_neighbours_predicted_boxes_are_drawn_faintly(racetrack):
    from driveopt.viz.overlay import CAR_LENGTH, CAR_WIDTH, PREDICTION_TIMES, decision_overlay, predicted_boxes

    env, ctrl = racetrack
    boxes = predicted_boxes(ctrl.planned, ctrl.driver.config)
    real = int(np.sum(np.asarray(ctrl.planned.problem.obstacle_mask) > 0))
    assert real > 0 and boxes.shape == (real * len(PREDICTION_TIMES), 4, 2)
    sides = np.hypot(*np.moveaxis(np.diff(boxes, axis=1, append=boxes[:, :1]), -1, 0))
    np.testing.assert_allclose(np.sort(sides, axis=1), [[CAR_WIDTH, CAR_WIDTH, CAR_LENGTH, CAR_LENGTH]] * len(boxes), atol=1e-9)
    plain = env.render()
    keywords = decision_overlay(ctrl.planned, ctrl.driver.config)
    with_boxes = driveopt.viz.video.draw_plan(plain, env, **keywords)
    without = driveopt.viz.video.draw_plan(plain, env, **{**keywords, "predicted": None})
    assert np.any(with_boxes != without), "the boxes change the frame"
    assert np.abs(with_boxes.astype(int) - without).max() < 200, "faintly"


def test_render_wrapper_and_errors(racetrack):
    env, ctrl = racetrack
    np.testing.assert_array_equal(driveopt.RenderPlans(env, ctrl).render(), ctrl.render(env))
    with pytest.raises(ControllerError, match="needs a driveopt.Controller"):
        driveopt.RenderPlans(env, object())
    blind = driveopt.gym_make("highway-v0", config=CONTINUOUS)
    blind.reset(seed=0)
    with pytest.raises(RenderError, match="render_mode='rgb_array'"):
        ctrl.render(blind)
    blind.close()


def test_drive_video_frames_carry_the_hud(tmp_path):
    import imageio.v2 as imageio

    from driveopt.cli import main

    video = tmp_path / "idm.mp4"
    assert main(["drive", "--scenario", "two-lane-d1.0", "--planner", "idm", "--duration", "0.3",
                 "--video", str(video)]) == 0
    frames = [f for f in imageio.get_reader(str(video), format="FFMPEG")]
    assert len(frames) == 3
    box, road = frames[0][6:24, 6:120].astype(int), frames[0][-40:, 6:120].astype(int)
    assert box.mean() > road.mean() + 40, "a light HUD box in the top-left corner"
    assert (box.sum(axis=-1) < 200).any(), "with text"
