"""Synthetic demonstrations for the learned-component tests, and the module-scoped fixtures the trainers' tests share.

Three kinds of rows: :func:`synthetic_rows` (set-points that are a fixed function of the observation, and the
trajectories the set-point QP makes of them, so a CVAE can fit them), :func:`synthetic_modes` (up to four distinct
plans per row, for the VQ-VAE and PixelCNN) and :func:`scene_rows` (observations of random four-lane scenes, for the
safety filter, whose training rebuilds each row's planning problem)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from driveopt.config import BasisConfig, QPConfig
from driveopt.data.demonstrations import DemonstrationWriter
from driveopt.observation import DUMMY_DX, OBSERVATION_DIM, observation_vector
from driveopt.qp import make_model, qp_layer
from driveopt.scene import EgoState, Neighbour, Road, Scene

LANES = (-2.0, 14.0)  # [m] y_lb, y_ub of a four-lane road
SCENARIO = "four-lane-d3.0"  # a registered four-lane scenario: checkpoints record its lane count
MODES = 4  # [-] mode slots of the files of write_modes
LANE_CENTRES = (0.0, 4.0, 8.0, 12.0)  # [m] of the four-lane road

RowMaker = Callable[[np.random.Generator, int], dict[str, np.ndarray]]


def synthetic_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    y0 = rng.choice(LANE_CENTRES, n) + rng.normal(0, 0.3, n)
    vx = rng.uniform(5.0, 20.0, n)
    obs = np.zeros((n, OBSERVATION_DIM), np.float32)
    obs[:, 0], obs[:, 1], obs[:, 2] = LANES[1] - y0, LANES[0] - y0, vx
    nb = obs[:, 5:].reshape(n, 10, 5)
    nb[:] = (DUMMY_DX, 0, 0, 0, 0)
    nb[:, 0] = np.stack([rng.uniform(10, 60, n), rng.choice([-4.0, 0.0, 4.0], n), rng.uniform(0, 15, n), 0 * vx, 0 * vx], -1)
    leader_ahead = nb[:, 0, 1] == 0.0
    target_y = np.clip(np.where(leader_ahead, y0 + 4.0, y0), 0.0, 12.0)  # change lanes when the leader is in ours
    speed = np.where(leader_ahead, vx, np.minimum(vx + 3.0, 20.0))
    setpoints = np.concatenate([np.repeat(speed[:, None], 4, 1), np.repeat(target_y[:, None], 4, 1)], 1).astype(np.float32)
    init_x = np.stack([0 * vx, vx, 0 * vx], -1).astype(np.float32)
    init_y = np.stack([y0, 0 * vx, 0 * vx], -1).astype(np.float32)
    return with_qp_plans({"observation": obs, "init_x": init_x, "init_y": init_y, "lane_bounds": np.tile(np.float32(LANES), (n, 1)),
                          "setpoints": setpoints}, n)


def with_qp_plans(rows: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """``rows`` (observation, initial state, lane bounds, set-points) completed with the set-point QP's plans
    (coefficients, trajectory [m]), status SUCCESS and times 0.1 s apart."""
    coeffs, positions = qp_layer(make_model(BasisConfig(), QPConfig()), QPConfig(), rows["setpoints"], rows["init_x"], rows["init_y"])
    return {**rows, "coeffs": np.asarray(coeffs), "trajectory": np.asarray(positions), "status": np.zeros(n, np.int8),
            "time": np.arange(n, dtype=np.float32) / 10.0}


def synthetic_modes(rng: np.random.Generator, rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """1..MODES modes per row: keep the lane, change left, change right, slow down (the set-point QP's plans)."""
    n = len(rows["observation"])
    y0, v = rows["init_y"][:, 0], rows["init_x"][:, 1]
    options = [(v, y0), (v, np.clip(y0 + 4.0, 0, 12)), (v, np.clip(y0 - 4.0, 0, 12)), (np.maximum(v - 5.0, 0.0), y0)]
    out = {"mode_setpoints": np.zeros((n, MODES, 8), np.float32), "mode_coeffs": np.zeros((n, MODES, 22), np.float32),
           "mode_cost": np.zeros((n, MODES), np.float32), "mode_residual": np.zeros((n, MODES), np.float32),
           "mode_mask": np.zeros((n, MODES), bool)}
    model = make_model(BasisConfig(), QPConfig())
    count = rng.integers(1, MODES + 1, n)
    for j, (speed, lateral) in enumerate(options):
        sp = np.concatenate([np.repeat(speed[:, None], 4, 1), np.repeat(lateral[:, None], 4, 1)], 1).astype(np.float32)
        coeffs, _ = qp_layer(model, QPConfig(), sp, rows["init_x"], rows["init_y"])
        use = count > j
        out["mode_setpoints"][use, j], out["mode_coeffs"][use, j] = sp[use], np.asarray(coeffs)[use]
        out["mode_cost"][use, j], out["mode_mask"][use, j] = float(j), True
    return out


def rows_with_modes(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    rows = synthetic_rows(rng, n)
    return {**rows, **synthetic_modes(rng, rows)}


def scene_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Demonstration rows of random four-lane scenes (observation, state and lane bounds as the closed loop stores
    them); the plan keeps speed and lane."""
    obs, init_x, init_y, bounds, setpoints = [], [], [], [], []
    for _ in range(n):
        y, vx = float(rng.choice(LANE_CENTRES) + rng.normal(0.0, 0.3)), float(rng.uniform(6.0, 14.0))
        neighbours = tuple(Neighbour(x=float(rng.uniform(8.0, 50.0)), y=float(rng.choice(LANE_CENTRES)),
                                     vx=float(rng.uniform(0.0, 10.0))) for _ in range(int(rng.integers(2, 5))))
        scene = Scene(ego=EgoState(x=0.0, y=y, vx=vx), road=Road(num_lanes=4), neighbours=neighbours)
        obs.append(observation_vector(scene))
        init_x.append([0.0, vx, 0.0])
        init_y.append([y, 0.0, 0.0])
        bounds.append(scene.lateral_bounds)
        setpoints.append([vx] * 4 + [y] * 4)
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return with_qp_plans({"observation": f32(obs), "init_x": f32(init_x), "init_y": f32(init_y), "lane_bounds": f32(bounds),
                          "setpoints": f32(setpoints)}, n)


def episode_entry(scenario: str, seed: int, episode: int, rows: int) -> dict[str, Any]:
    """The episode table's entry of a collision-free episode of ``rows`` rows (0.1 s each)."""
    return {"scenario": scenario, "seed": seed, "episode": episode, "env_seed": episode, "collided": False,
            "duration": rows / 10.0}


def write_episodes(path: str | Path, make_rows: RowMaker, episodes: int, rows: int, seed: int, scenario: str = SCENARIO,
                   **writer_options: Any) -> Path:
    """A demonstrations file of ``episodes`` collision-free episodes of ``make_rows(rng, rows)``, one generator seeded
    ``seed`` for all of them (``writer_options``: e.g. ``max_modes``)."""
    rng = np.random.default_rng(seed)
    writer = DemonstrationWriter(path, {"expert": "synthetic"}, BasisConfig().num_nodes, 22, OBSERVATION_DIM, **writer_options)
    for e in range(episodes):
        writer.append_episode(episode_entry(scenario, seed, e, rows), make_rows(rng, rows))
    return Path(path)


def write_synthetic(path: str | Path, episodes: int = 4, rows: int = 64, seed: int = 0, scenario: str = SCENARIO) -> Path:
    return write_episodes(path, synthetic_rows, episodes, rows, seed, scenario)


def write_modes(path: str | Path, episodes: int = 4, rows: int = 48, seed: int = 0, scenario: str = SCENARIO) -> Path:
    """:func:`synthetic_rows` with :func:`synthetic_modes` (schema version 2, MODES slots)."""
    return write_episodes(path, rows_with_modes, episodes, rows, seed, scenario, max_modes=MODES)


def write_scenes(path: str | Path, episodes: int = 3, rows: int = 6, seed: int = 0, scenario: str = SCENARIO) -> Path:
    return write_episodes(path, scene_rows, episodes, rows, seed, scenario)


def write_demonstrations(path: Path, episodes: int = 2, rows: int = 6) -> Path:
    """Synthetic rows on a four-lane road whose lane bounds are the ego centre's (-1, 13) m, as collect writes them."""

    def centre_bounds_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
        data = synthetic_rows(rng, n)
        y0 = data["init_y"][:, 0]
        data["lane_bounds"][:] = (-1.0, 13.0)
        data["observation"][:, 0], data["observation"][:, 1] = 13.0 - y0, -1.0 - y0
        return data

    return write_episodes(path, centre_bounds_rows, episodes, rows, seed=0)


# ------------------------------------------------------------------------------------------- fixtures


def file_fixture(write: Callable[[Path], Path], name: str) -> Any:
    """A module-scoped fixture: the file ``write`` makes at ``name`` in a temporary folder, once per test module."""

    @pytest.fixture(scope="module")
    def made(tmp_path_factory):
        return write(tmp_path_factory.mktemp("demo") / name)

    return made


def trained_fixture(train: Callable[[Path, Path], Any], data_fixture: str = "data_file") -> Any:
    """A module-scoped fixture: (output folder, ``train(data file, folder)``), trained once per test module on the
    file of the fixture named ``data_fixture``."""

    @pytest.fixture(scope="module")
    def trained(request, tmp_path_factory):
        out = tmp_path_factory.mktemp("trained")
        return out, train(request.getfixturevalue(data_fixture), out)

    return trained
