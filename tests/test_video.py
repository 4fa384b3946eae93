"""Video overlay: pixel alignment with the simulator's own drawing, MP4 round trip, bad input."""

import os

import numpy as np
import pytest

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

from driveopt.sim.env import make_env  # noqa: E402
from driveopt.sim.scenarios import get_scenario  # noqa: E402
from driveopt.viz.video import CHOSEN_RGBA, VideoWriter, draw_plan, world_to_pixel  # noqa: E402


@pytest.fixture(scope="module")
def rendered():
    env = make_env(get_scenario("four-lane-d1.0"), render_mode="rgb_array")
    env.reset(seed=3)
    frame = env.render()
    yield env, frame
    env.close()


def test_ego_pixel_is_where_the_simulator_draws_the_ego(rendered):
    env, frame = rendered
    ego = env.unwrapped.vehicle
    px, py = np.round(world_to_pixel(env, ego.position)).astype(int)
    assert 0 <= px < frame.shape[1] and 0 <= py < frame.shape[0]
    # upstream draws the ego in yellow-green (EGO colour); its centre pixel is not road grey
    assert not np.all(frame[py, px] == frame[py, px][0])
    x, y = ego.position
    chosen = np.stack([np.linspace(x, x + 40, 50), np.full(50, y)], axis=1)
    out = draw_plan(frame, env, chosen=chosen)
    ahead = np.round(world_to_pixel(env, [x + 20, y])).astype(int)
    assert tuple(out[ahead[1], ahead[0]]) == CHOSEN_RGBA[:3]
    assert out.shape == frame.shape and not np.array_equal(out, frame)


def test_off_screen_points_are_ignored(rendered):
    env, frame = rendered
    far = np.stack([np.linspace(1e5, 2e5, 10), np.zeros(10)], axis=1)
    out = draw_plan(frame, env, samples=far[None], elites=far[None], chosen=far)
    np.testing.assert_array_equal(out, frame)


def test_mp4_round_trip_and_shape_errors(rendered, tmp_path):
    import imageio.v2 as imageio

    _, frame = rendered
    path = tmp_path / "sub" / "clip.mp4"
    with VideoWriter(path, fps=10) as writer:
        for _ in range(10):
            writer.append(frame)
        with pytest.raises(ValueError, match="shape changed"):
            writer.append(frame[:, :-2])
    frames = [f for f in imageio.get_reader(str(path), format="FFMPEG")]  # list() asks len(): inf
    assert len(frames) == 10 and frames[0].shape == frame.shape
    with pytest.raises(ValueError, match="uint8"):
        draw_plan(frame.astype(float), rendered[0])
