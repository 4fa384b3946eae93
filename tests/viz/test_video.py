"""Video overlay: pixel alignment with the simulator's own drawing, clipping at the frame edge, legend,
MP4 round trip (odd sizes padded), bad input and the black-frame ``dummy`` driver."""

import os
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import reset_env

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

from driveopt.sim.scenarios import get_scenario
from driveopt.viz.video import (
    CHOSEN_RGBA,
    ELITE_RGBA,
    FALLBACK_RGBA,
    VideoWriter,
    check_video_driver,
    clip_polyline,
    draw_plan,
    pad_to_even,
    world_to_pixel,
)


@pytest.fixture(scope="module")
def rendered():
    env = reset_env(get_scenario("four-lane-d1.0"), render_mode="rgb_array", seed=3)
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


# --- clipping, legend, padding, driver: a fake env whose world frame is the pixel frame ------------

W, H = 600, 150
GREY = 100


def pixel_env(origin=(0.0, 0.0), scaling=1.0):
    surface = SimpleNamespace(origin=origin, scaling=scaling)
    return SimpleNamespace(unwrapped=SimpleNamespace(viewer=SimpleNamespace(sim_surface=surface)))


@pytest.fixture
def grey():
    return np.full((H, W, 3), GREY, np.uint8)


def changed(out, frame):
    return np.any(out != frame, axis=-1)


def test_polyline_leaving_and_reentering_the_frame_leaves_the_gap_empty(grey):
    # in at the left, up and out through the top, far off screen, back down at the right
    path = np.array([[20, 50], [40, 50], [40, -1500], [560, -1500], [560, 50], [580, 50]], float)
    out = draw_plan(grey, pixel_env(), chosen=path, legend=False)
    hit = changed(out, grey)
    assert not hit[:, 50:550].any()  # nothing drawn across the gap (the old code joined 40 -> 560)
    # both pieces are drawn, each up to the top edge
    assert tuple(out[50, 30]) == CHOSEN_RGBA[:3] and tuple(out[50, 570]) == CHOSEN_RGBA[:3]
    assert tuple(out[0, 40]) == CHOSEN_RGBA[:3] and tuple(out[0, 560]) == CHOSEN_RGBA[:3]
    pieces = clip_polyline(path, (W, H))
    assert len(pieces) == 2
    np.testing.assert_allclose(pieces[0], [[20, 50], [40, 50], [40, 0]])
    np.testing.assert_allclose(pieces[1], [[560, 0], [560, 50], [580, 50]])


def test_segment_crossing_the_edge_is_drawn_up_to_the_edge_pixel(grey):
    env = pixel_env()
    out = draw_plan(grey, env, chosen=np.array([[300.0, 75.0], [1e6, 75.0]]), legend=False)
    assert np.all(out[75, 300:] == CHOSEN_RGBA[:3])  # the old code dropped the far point: no line
    out = draw_plan(grey, env, chosen=np.array([[300.0, 75.0], [300.0, -1e7]]), fallback=True, legend=False)
    assert np.all(out[:76, 300] == FALLBACK_RGBA[:3])
    # a diagonal through two edges is cut exactly where it meets them
    (piece,) = clip_polyline(np.array([[-10.0, -10.0], [700.0, 160.0]]), (W, H))
    np.testing.assert_allclose(piece, [[10 / 170 * 710 - 10, 0], [W - 1, -10 + 170 * (W - 1 + 10) / 710]])
    # a world-frame offset and scale go through the same clipping
    far = pixel_env(origin=(-10.0, 0.0), scaling=2.0)
    out = draw_plan(grey, far, chosen=np.array([[140.0, 37.5], [1e5, 37.5]]), legend=False)
    assert np.all(out[75, 300:] == CHOSEN_RGBA[:3])


def test_clip_polyline_edge_cases():
    size = (W, H)
    assert clip_polyline(np.zeros((1, 2)), size) == []
    assert clip_polyline(np.array([[-5.0, -5.0], [-5.0, 500.0]]), size) == []  # parallel to the edge, outside
    assert clip_polyline(np.array([[1e6, 1e6], [2e6, -2e6]]), size) == []
    inside = np.array([[10.0, 10.0], [20.0, 20.0], [30.0, 10.0]])
    (piece,) = clip_polyline(inside, size)
    np.testing.assert_array_equal(piece, inside)
    # a non-finite point splits the polyline
    pieces = clip_polyline(np.array([[10, 10], [20, 20], [np.nan, 0], [40, 40], [50, 40]], float), size)
    assert [p.tolist() for p in pieces] == [[[10, 10], [20, 20]], [[40, 40], [50, 40]]]
    # touching the edge at a vertex and turning back stays one piece
    (piece,) = clip_polyline(np.array([[10.0, 50.0], [20.0, 0.0], [30.0, 50.0]]), size)
    assert len(piece) == 3
    # the margin grows the box: a line 1 px outside is kept for a thick stroke
    line = np.array([[10.0, -1.0], [50.0, -1.0]])
    assert clip_polyline(line, size) == [] and len(clip_polyline(line, size, margin=2.0)) == 1


def test_legend_names_the_colours_in_the_corner(grey):
    env = pixel_env()
    chosen = np.array([[20.0, 40.0], [300.0, 40.0]])
    bare = draw_plan(grey, env, chosen=chosen, legend=False)
    out = draw_plan(grey, env, chosen=chosen, elites=chosen[None] + [0, 10])
    corner = out[H // 2 :, W // 2 :].reshape(-1, 3)
    colours = {tuple(c) for c in corner}
    assert {CHOSEN_RGBA[:3], FALLBACK_RGBA[:3], ELITE_RGBA[:3]} <= colours
    assert not np.array_equal(out[H // 2 :, W // 2 :], bare[H // 2 :, W // 2 :])
    assert np.array_equal(bare[H // 2 :, W // 2 :], grey[H // 2 :, W // 2 :])
    # nothing in view: no legend either
    np.testing.assert_array_equal(draw_plan(grey, env, chosen=chosen + 1e4), grey)


def test_odd_frames_are_padded_to_even(tmp_path):
    import imageio.v2 as imageio

    odd = np.random.default_rng(0).integers(0, 255, (75, 151, 3), dtype=np.uint8)
    padded = pad_to_even(odd)
    assert padded.shape == (76, 152, 3)
    np.testing.assert_array_equal(padded[:75, :151], odd)
    np.testing.assert_array_equal(padded[75, :151], odd[74])
    np.testing.assert_array_equal(padded[:75, 151], odd[:, 150])
    even = odd[:74, :150]
    assert pad_to_even(even) is even or np.array_equal(pad_to_even(even), even)
    path = tmp_path / "odd.mp4"
    with VideoWriter(path, fps=5) as writer:
        for _ in range(3):
            writer.append(odd)
        with pytest.raises(ValueError, match="shape changed"):
            writer.append(padded)
    frames = [f for f in imageio.get_reader(str(path), format="FFMPEG")]
    assert len(frames) == 3 and frames[0].shape == (76, 152, 3)


def test_dummy_video_driver_is_a_clear_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    with pytest.raises(ValueError, match="dummy.*black frames.*SDL_VIDEODRIVER=offscreen"):
        VideoWriter(tmp_path / "x.mp4", fps=5)
    assert not (tmp_path / "x.mp4").exists()
    from driveopt.cli import main

    assert main(["drive", "--scenario", "two-lane-d1.0", "--planner", "grid", "--duration", "0.5",
                 "--video", str(tmp_path / "y.mp4")]) == 2
    err = capsys.readouterr().err
    assert "driveopt: error:" in err and "dummy" in err and not (tmp_path / "y.mp4").exists()
    # the driver pygame's display really runs with counts too
    monkeypatch.setenv("SDL_VIDEODRIVER", "offscreen")
    display = SimpleNamespace(get_init=lambda: True, get_driver=lambda: "dummy")
    monkeypatch.setitem(sys.modules, "pygame", SimpleNamespace(display=display))
    with pytest.raises(ValueError, match="dummy"):
        check_video_driver()
    display.get_driver = lambda: "offscreen"
    check_video_driver()


def test_a_truncated_video_is_an_error_and_leaves_no_file(tmp_path, monkeypatch):
    """A full disk cut the MP4 at 4 KB and drive printed "wrote": the writer checks the file ffmpeg finished."""
    from driveopt.viz.video import VideoError, mp4_problem

    frames = np.random.default_rng(0).integers(0, 255, (5, 64, 96, 3), dtype=np.uint8)
    with VideoWriter(tmp_path / "whole.mp4", fps=5) as writer:
        for frame in frames:
            writer.append(frame)
    whole = (tmp_path / "whole.mp4").read_bytes()
    assert mp4_problem(tmp_path / "whole.mp4") is None
    (tmp_path / "cut.mp4").write_bytes(whole[:4096])
    assert mp4_problem(tmp_path / "cut.mp4").startswith("truncated at 4096 bytes")

    writer = VideoWriter(tmp_path / "full.mp4", fps=5)
    for frame in frames:
        writer.append(frame)
    close = writer._writer.close

    def close_on_a_full_disk():  # ffmpeg ends without an error, but the disk kept only the first 4 KB
        close()
        with open(writer._tmp, "r+b") as f:
            f.truncate(4096)

    monkeypatch.setattr(writer._writer, "close", close_on_a_full_disk)
    with pytest.raises(VideoError, match="full.mp4: the MP4 ffmpeg wrote is incomplete"):
        writer.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mp4", "whole.mp4"]


def test_a_failed_episode_leaves_no_video(tmp_path):
    with pytest.raises(RuntimeError, match="episode failed"), VideoWriter(tmp_path / "v.mp4", fps=5) as writer:
        writer.append(np.zeros((32, 48, 3), np.uint8))
        raise RuntimeError("episode failed")
    assert list(tmp_path.iterdir()) == []
