"""Offline prior metrics: best of N, feasible share, distinct lanes; the problem of a demonstration row;
the resumable command line (``python -m driveopt.experiments.prior_metrics``)."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from learned_data import write_demonstrations

from driveopt.config import PlannerConfig
from driveopt.data.demonstrations import DatasetError
from driveopt.data.replay import road_from_bounds, scene_from_observation
from driveopt.experiments.prior_metrics import (
    MetricError,
    RowMetrics,
    best_of_n,
    distinct_lanes,
    evaluation_config,
    feasible_count,
    main,
    proposal_positions,
    row_metrics,
    summarise,
)
from driveopt.observation import observation_vector
from driveopt.planner import RowKind
from driveopt.problem import build_problem
from driveopt.sampler import Proposal, moments
from driveopt.scene import EgoState, Road, Scene, load_scene

@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FixedPrior:
    """Proposes its rows of set-points over and over: a prior whose metrics can be worked out by hand."""

    setpoints: jnp.ndarray  # (M, 8)

    def propose(self, problem, key, num, warm_mean=None) -> Proposal:
        samples = jnp.tile(self.setpoints, (-(-num // self.setpoints.shape[0]), 1))[:num]
        return Proposal(samples, *moments(samples, 0.01))


def test_best_of_n_is_the_closest_sample_by_mean_squared_node_distance():
    expert = np.zeros((3, 2))
    positions = np.array([
        [[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]],  # 1 m off at every node: 1 m^2
        [[0.0, 0.0], [0.0, 3.0], [0.0, 0.0]],  # 3 m off at one node of three: 3 m^2
        [[0.0, 0.0], [0.0, 0.0], [0.6, 0.8]],  # 1 m off at one node: 1/3 m^2
    ])
    assert best_of_n(positions, expert) == pytest.approx(1.0 / 3.0)
    assert best_of_n(positions[:2], expert) == pytest.approx(1.0)
    assert best_of_n(positions[:2] + 2.0, expert + 2.0) == pytest.approx(1.0)  # frame-independent
    with pytest.raises(MetricError, match="S >= 1"):
        best_of_n(positions[:0], expert)
    with pytest.raises(MetricError):
        best_of_n(positions, np.zeros((4, 2)))


def test_feasible_count_counts_only_samples_within_the_tolerance():
    kind = np.array([RowKind.SAMPLE] * 4 + [RowKind.COMFORTABLE_STOP, RowKind.EMERGENCY_STOP])
    residual = np.array([0.0, 0.05, 0.06, 1.0, 0.0, 0.0])  # the stops are feasible but are not samples
    assert feasible_count(residual, kind, 0.05) == 2
    assert feasible_count(residual, kind, 0.0) == 1 and feasible_count(residual, kind, 10.0) == 4
    with pytest.raises(MetricError):
        feasible_count(residual[:3], kind, 0.05)
    assert distinct_lanes(np.array([1, 1, 2, 0, 2])) == 3 and distinct_lanes(np.array([3])) == 1


def test_summarise_gives_medians_and_the_share_of_rows_with_a_feasible_sample():
    rows = [RowMetrics(10.0, 0, 1, 0), RowMetrics(30.0, 5, 3, 2), RowMetrics(20.0, 250, 2, 2), RowMetrics(100.0, 0, 1, 0)]
    stats = summarise(rows)
    assert stats["rows"] == 4
    assert stats["best_of_n_median"] == pytest.approx(25.0) and stats["best_of_n_mean"] == pytest.approx(40.0)
    assert stats["feasible_share"] == pytest.approx(0.5) and stats["feasible_median"] == pytest.approx(2.5)
    assert stats["lanes_median"] == pytest.approx(1.5) and stats["feasible_lanes_median"] == pytest.approx(1.0)
    with pytest.raises(MetricError):
        summarise([])


def test_a_rows_scene_is_read_back_from_its_observation():
    scene = load_scene("dense-snapshot")  # ego at x = 0, 10 neighbours of 5 x 2 m, 4 lanes at 0, 4, 8, 12
    ego = scene.ego
    rebuilt = scene_from_observation(observation_vector(scene), np.array([0.0, ego.vx, ego.ax]), np.array([ego.y, ego.vy, ego.ay]),
                                     np.array(scene.lateral_bounds), scene.v_des)
    assert rebuilt.road == scene.road
    assert sorted((n.x, n.y, n.vx, n.vy) for n in rebuilt.neighbours) == sorted((n.x, n.y, n.vx, n.vy) for n in scene.neighbours)
    a, b = build_problem(scene, ignore_followers=True), build_problem(rebuilt, ignore_followers=True)
    for field in ("obstacle_x", "obstacle_y", "obstacle_a", "obstacle_b", "obstacle_mask", "observation", "y_lb", "y_ub"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-4, err_msg=field)
    assert road_from_bounds(-1.0, 5.0) == Road(num_lanes=2, lane_width=4.0, first_lane_center=0.0)
    with pytest.raises(DatasetError, match="no whole number"):
        road_from_bounds(-2.0, 14.0)


def test_row_metrics_of_a_hand_made_prior_on_an_empty_road():
    """Half the samples keep lane 1 at 10 m/s, half change to lane 2: the expert kept its lane. On an empty road every
    sample projects feasibly: best of N 0 m^2, all 8 samples feasible, 2 lanes among them and among the feasible plans."""
    scene = Scene(ego=EgoState(x=0.0, y=4.0, vx=10.0), road=Road(num_lanes=4))
    config = evaluation_config(PlannerConfig().replace(projection={"max_iterations": 20}), samples=8)
    problem = build_problem(scene, config.basis)
    keep, change = [10.0] * 4 + [4.0] * 4, [10.0] * 4 + [8.0] * 4
    one_lane_prior = FixedPrior(jnp.array([keep, keep], jnp.float32))  # the same shapes as ``prior``: one compilation
    prior = FixedPrior(jnp.array([keep, change], jnp.float32))
    _, expert = proposal_positions(one_lane_prior, problem, jax.random.PRNGKey(0), 4, config.basis, config.qp)
    expert = np.asarray(expert[0])
    metrics = row_metrics(prior, problem, expert, config, jax.random.PRNGKey(3), best_of=4)
    assert metrics.best_of_n == pytest.approx(0.0, abs=1e-6)
    assert (metrics.feasible, metrics.lanes, metrics.feasible_lanes) == (8, 2, 2)
    one_lane = row_metrics(one_lane_prior, problem, expert + [0.0, 1.0], config, jax.random.PRNGKey(3), best_of=4)
    assert one_lane.best_of_n == pytest.approx(1.0, abs=1e-4)  # 1 m beside the expert at every node
    assert (one_lane.feasible, one_lane.lanes, one_lane.feasible_lanes) == (8, 1, 1)


# ------------------------------------------------------------------------------------------ the command line


def test_the_script_writes_json_resumes_and_refuses_other_settings(tmp_path, capsys):
    data = write_demonstrations(tmp_path / "held.h5")
    out = tmp_path / "metrics.json"
    args = ["--data", str(data), "--json", str(out), "--priors", "gaussian", "--max-rows", "2", "--samples", "16", "--best-of", "4"]
    assert main(args) == 0
    report = json.loads(out.read_text())
    stats = report["results"]["gaussian"]
    assert stats["rows"] == 2 and 0.0 <= stats["feasible_share"] <= 1.0 and 1 <= stats["lanes_median"] <= 4
    assert report["settings"]["samples"] == 16 and report["settings"]["priors"] == ["gaussian"]
    lines = (tmp_path / "metrics.rows.jsonl").read_text().splitlines()
    assert len(lines) == 3 and json.loads(lines[0])["settings"] == report["settings"]
    # A torn last line is redone; finished rows are kept.
    (tmp_path / "metrics.rows.jsonl").write_text("\n".join(lines[:2]) + '\n{"prior": "gau')
    assert main(args) == 0
    assert (tmp_path / "metrics.rows.jsonl").read_text().splitlines()[:2] == lines[:2]
    assert json.loads(out.read_text())["results"]["gaussian"]["rows"] == 2
    capsys.readouterr()
    assert main([*args[:-4], "--samples", "20", "--best-of", "4"]) == 2
    assert "other settings (samples)" in capsys.readouterr().err
    assert main([*args, "--vqvae-weights", str(tmp_path / "none.ckpt"), "--priors", "vqvae"]) == 2
    assert "cannot read checkpoint" in capsys.readouterr().err
