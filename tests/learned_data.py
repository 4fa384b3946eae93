"""Synthetic demonstrations for the learned-component tests: set-points that are a fixed function of
the observation, and the trajectories the set-point QP makes of them (so a CVAE can fit them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from driveopt.config import BasisConfig, QPConfig
from driveopt.data.demonstrations import DemonstrationWriter
from driveopt.observation import DUMMY_DX, OBSERVATION_DIM
from driveopt.qp import make_model, qp_layer

LANES = (-2.0, 14.0)  # [m] y_lb, y_ub of a four-lane road
SCENARIO = "four-lane-d3.0"  # a registered four-lane scenario: checkpoints record its lane count


def synthetic_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    y0 = rng.choice([0.0, 4.0, 8.0, 12.0], n) + rng.normal(0, 0.3, n)
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
    coeffs, positions = qp_layer(make_model(BasisConfig(), QPConfig()), QPConfig(), setpoints, init_x, init_y)
    return {"observation": obs, "init_x": init_x, "init_y": init_y, "lane_bounds": np.tile(np.float32(LANES), (n, 1)),
            "setpoints": setpoints, "coeffs": np.asarray(coeffs), "trajectory": np.asarray(positions),
            "status": np.zeros(n, np.int8), "time": np.arange(n, dtype=np.float32) / 10.0}


def write_synthetic(path: str | Path, episodes: int = 4, rows: int = 64, seed: int = 0, scenario: str = SCENARIO) -> Path:
    rng = np.random.default_rng(seed)
    writer = DemonstrationWriter(path, {"expert": "synthetic"}, BasisConfig().num_nodes, 22, OBSERVATION_DIM)
    for e in range(episodes):
        entry = {"scenario": scenario, "seed": seed, "episode": e, "env_seed": e, "collided": False, "duration": rows / 10.0}
        writer.append_episode(entry, synthetic_rows(rng, rows))
    return Path(path)


def write_demonstrations(path: Path, episodes: int = 2, rows: int = 6) -> Path:
    """Synthetic rows on a four-lane road whose lane bounds are the ego centre's (-1, 13) m, as collect writes them."""
    rng = np.random.default_rng(0)
    writer = DemonstrationWriter(path, {"expert": "synthetic"}, BasisConfig().num_nodes, 22, OBSERVATION_DIM)
    for e in range(episodes):
        data = synthetic_rows(rng, rows)
        y0 = data["init_y"][:, 0]
        data["lane_bounds"][:] = (-1.0, 13.0)
        data["observation"][:, 0], data["observation"][:, 1] = 13.0 - y0, -1.0 - y0
        writer.append_episode({"scenario": "four-lane-d3.0", "seed": 0, "episode": e, "env_seed": e, "collided": False,
                               "duration": rows / 10.0}, data)
    return path
