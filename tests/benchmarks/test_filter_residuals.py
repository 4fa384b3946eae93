"""benchmarks/studies/filter_residuals.py: residuals after k projection iterations with the learned filter and with
the plain projection, on held-out demonstration rows; resumable output and one-line errors.

Every run shares one setting (8 samples, k = 1 and 25, the ``vqvae-filter`` projection),
so its projections compile once for the file."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from learned_data import write_demonstrations
from tiny_models import random_params, tiny_pixelcnn

from driveopt.learned import filter as fl
from driveopt.learned.checkpoint import save_checkpoint
from driveopt.registry import get_optimiser

from benchmarks.studies import filter_residuals as SCRIPT

CFG = fl.FilterConfig(hidden=(16, 16))
ITERATIONS = [1, 25]
ROWS = 3


def tiny_filter(path: Path, params, lanes=(4,)) -> Path:
    """A filter checkpoint with ``params``, an identity normaliser, recorded as trained on Gaussian samples for
    ``lanes``-lane roads."""
    normaliser = fl.Normaliser(jnp.zeros(CFG.input_dim, jnp.float32), jnp.ones(CFG.input_dim, jnp.float32))
    meta = {"config": CFG.to_dict(), "lanes": list(lanes), "prior": {"samples_from": "gaussian", "weights": None}}
    return save_checkpoint(path, fl.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser}, meta)


def arguments(data: Path, weights: Path, out: Path, *extra: str) -> list[str]:
    return ["--data", str(data), "--filter-weights", str(weights), "--json", str(out), "--max-rows", str(ROWS),
            "--samples", "8", "--iterations", *map(str, reversed(ITERATIONS)), *extra]  # given unsorted: measured sorted


def rows_of(out: Path) -> list[dict]:
    lines = out.with_name(out.stem + ".rows.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines[1:]]


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """(folder, data, random filter, its summary, plain-params filter, its summary): a random (untrained) network whose
    output layer moves gammas, multipliers and first iterate, and the same network with the plain output layer."""
    tmp = tmp_path_factory.mktemp("residuals")
    data = write_demonstrations(tmp / "held.h5")  # 2 episodes of 6 rows, four lanes
    params = random_params(fl.init_params, CFG, 0)
    random = tiny_filter(tmp / "random.ckpt", params)
    projection = get_optimiser("vqvae-filter").config.projection
    # The plain variant runs the configured projection: barrier mode with gammas 1, which plain_params reproduces exactly.
    assert projection.barrier and (projection.gamma_obs, projection.gamma_lane) == (1.0, 1.0)
    plain = tiny_filter(tmp / "plain.ckpt", fl.plain_params(params, CFG, projection.gamma_obs, projection.gamma_lane))
    summaries = []
    for weights in (random, plain):
        out = tmp / f"{weights.stem}.json"
        assert SCRIPT.main(arguments(data, weights, out)) == 0  # --samples-from: the checkpoint's (gaussian)
        summaries.append(json.loads(out.read_text()))
    return tmp, data, random, summaries[0], plain, summaries[1]


def test_both_variants_are_measured_at_every_k_with_finite_residuals(measured):
    tmp, _, _, report, _, _ = measured
    settings = report["settings"]
    assert settings["iterations"] == ITERATIONS and settings["samples"] == 8 and settings["rows"] == ROWS
    assert settings["prior"] == {"samples_from": "gaussian", "weights": None} and settings["planner"] == "vqvae-filter"
    assert {"platform", "cpus", "jax", "device"} <= set(report["machine"])
    assert report["rows"] == ROWS and report["residual_tolerance"] == pytest.approx(0.05)
    rows = rows_of(tmp / "random.json")
    assert len(rows) == ROWS and len({r["row"] for r in rows}) == ROWS
    for variant in ("learned", "plain"):
        summary = report["results"][variant]
        assert sorted(summary["by_iterations"]) == sorted(map(str, ITERATIONS))
        for k in ITERATIONS:
            cell = summary["by_iterations"][str(k)]
            assert np.isfinite(cell["residual_median"]) and cell["residual_median"] >= 0.0
            assert 0.0 <= cell["feasible_share"] <= 1.0 and 1.0 <= cell["iterations_mean"] <= k
            per_row = [r["results"][variant][str(k)] for r in rows]
            assert cell["residual_median"] == pytest.approx(np.median([c["residual_median"] for c in per_row]))
            assert cell["feasible_share"] == pytest.approx(np.mean([c["feasible_share"] for c in per_row]))
            assert all(np.isfinite(c["residual_median"]) and c["residual_median"] >= 0.0 and 1 <= c["iterations"] <= k
                       for c in per_row)
            for r, c in ((r, r["results"][variant][str(k)]) for r in rows):  # the split shares make up the whole
                change, keep = c["lane_change_feasible_share"], c["keep_lane_feasible_share"]
                whole = r["lane_change_share"] * (change or 0.0) + (1.0 - r["lane_change_share"]) * (keep or 0.0)
                assert (change is None) == (r["lane_change_share"] == 0.0) and (keep is None) == (r["lane_change_share"] == 1.0)
                assert whole == pytest.approx(c["feasible_share"], abs=1e-9)
                assert (c["chosen_speed"] is None) == (c["feasible_share"] == 0.0)  # the pick exists iff a sample is feasible
                assert c["chosen_speed"] is None or (c["chosen_speed"] >= 0.0 and np.isfinite(c["chosen_cost"]))
        reached = [k for k in ITERATIONS if summary["by_iterations"][str(k)]["residual_median"] <= report["residual_tolerance"]]
        assert summary["iterations_to_tolerance"] == (reached[0] if reached else None)
    # The random network does set the projection up differently from the plain projection.
    assert any(r["results"]["learned"][str(k)] != r["results"]["plain"][str(k)] for r in rows for k in ITERATIONS)


def test_lane_changing_samples_end_over_half_a_lane_from_the_ego():
    setpoints = np.array([[10, 10, 10, 10, 4.0, 4.5, 5.0, 5.9], [10, 10, 10, 10, 4.0, 8.0, 8.0, 6.1],
                          [10, 10, 10, 10, 0.0, 0.0, 1.0, 1.9], [10, 10, 10, 10, 4.0, 4.0, 4.0, 8.0]])
    assert SCRIPT.lane_changes(setpoints, ego_y=4.0, lane_width=4.0).tolist() == [False, True, True, True]


def test_the_pick_is_the_least_cost_feasible_sample():
    feasible = np.array([False, True, True, False])
    assert SCRIPT.chosen(feasible, np.array([0.1, 5.0, 3.0, 1.0]), np.array([20.0, 8.0, 9.0, 15.0])) == (3.0, 9.0)
    assert SCRIPT.chosen(np.zeros(4, bool), np.ones(4), np.ones(4)) == (None, None)


def test_a_filter_with_gamma_one_and_zero_initialisation_measures_as_the_plain_projection(measured):
    tmp, _, _, _, _, report = measured
    rows = rows_of(tmp / "plain.json")
    assert len(rows) == ROWS
    for row in rows:
        for k in ITERATIONS:
            learned, plain = row["results"]["learned"][str(k)], row["results"]["plain"][str(k)]
            assert learned["residual_median"] == pytest.approx(plain["residual_median"], rel=1e-5, abs=1e-6), (row["row"], k)
            assert learned["feasible_share"] == plain["feasible_share"] and learned["iterations"] == plain["iterations"]
    results = report["results"]
    assert results["learned"]["iterations_to_tolerance"] == results["plain"]["iterations_to_tolerance"]


def test_more_iterations_lower_the_plain_residual(measured):
    """From 1 to 25 iterations of the plain projection, the median sample's residual falls on every row (on these
    rows, by a factor of 7 to 90) and so does the summary's median over rows."""
    tmp, _, _, report, _, _ = measured
    for row in rows_of(tmp / "random.json"):
        first, last = (row["results"]["plain"][str(k)]["residual_median"] for k in (1, 25))
        assert last < 0.5 * first, (row["row"], first, last)
    by_k = report["results"]["plain"]["by_iterations"]
    assert by_k["25"]["residual_median"] < 0.5 * by_k["1"]["residual_median"]
    assert by_k["25"]["feasible_share"] >= by_k["1"]["feasible_share"]


def test_samples_from_a_learned_prior_are_measured_and_its_road_is_checked(measured, tmp_path, capsys):
    tmp, data, random, _, _, _ = measured
    out = tmp_path / "vqvae.json"
    pixelcnn = tiny_pixelcnn(tmp_path / "pixelcnn.ckpt")
    assert SCRIPT.main(arguments(data, random, out, "--samples-from", "vqvae", "--prior-weights", str(pixelcnn))) == 0
    report = json.loads(out.read_text())
    assert report["settings"]["prior"]["samples_from"] == "vqvae"
    assert "trained on samples of another prior" in capsys.readouterr().err  # the filter's record says gaussian
    for variant in ("learned", "plain"):
        assert all(np.isfinite(c["residual_median"]) for c in report["results"][variant]["by_iterations"].values())
    two_lane = tiny_pixelcnn(tmp_path / "two-lane.ckpt", lanes=(2,))
    args = arguments(data, random, tmp_path / "bad.json", "--samples-from", "vqvae", "--prior-weights", str(two_lane))
    assert SCRIPT.main(args) == 2
    assert "not this 4-lane road" in capsys.readouterr().err


def test_a_rerun_resumes_and_other_settings_are_refused(measured, tmp_path, capsys):
    tmp, data, random, report, _, _ = measured
    out = tmp_path / "resume.json"
    rows_file = tmp_path / "resume.rows.jsonl"
    lines = (tmp / "random.rows.jsonl").read_text().splitlines()
    rows_file.write_text("\n".join(lines[:-1]) + '\n{"row": 11, "resul')  # interrupted while writing the last row
    assert SCRIPT.main(arguments(data, random, out)) == 0  # redoes the last row only
    redone = rows_file.read_text().splitlines()
    assert redone[:-1] == lines[:-1] and json.loads(redone[-1]) == json.loads(lines[-1])
    assert json.loads(out.read_text())["results"] == report["results"]
    assert SCRIPT.main(arguments(data, random, out)) == 0  # nothing left to do
    assert rows_file.read_text().splitlines() == redone
    capsys.readouterr()
    assert SCRIPT.main(arguments(data, random, out, "--samples", "12")) == 2
    err = capsys.readouterr().err
    assert "error:" in err and "other settings (samples)" in err and len(err.strip().splitlines()) == 1
    assert rows_file.read_text().splitlines() == redone


def test_bad_checkpoints_data_and_options_exit_with_a_one_line_error(measured, tmp_path, capsys):
    tmp, data, random, _, _, _ = measured
    header, body = random.read_bytes().split(b"\n", 1)
    damaged = tmp_path / "damaged.ckpt"
    damaged.write_bytes(header + b"\n" + body[: len(body) // 2])
    two_lane = tiny_filter(tmp_path / "two-lane.ckpt", random_params(fl.init_params, CFG, 0), lanes=(2,))
    garbage = tmp_path / "garbage.h5"
    garbage.write_text("not HDF5")
    out = tmp_path / "bad.json"
    capsys.readouterr()
    for args, message in (
        (arguments(data, damaged, out), "corrupted"),
        (arguments(data, tmp_path / "missing.ckpt", out), "cannot read checkpoint"),
        (arguments(data, two_lane, out), "not this 4-lane road"),
        (arguments(garbage, random, out), "cannot read demonstrations"),
        (arguments(tmp_path / "missing.h5", random, out), "does not exist"),
        ([*arguments(data, random, out), "--iterations"], "at least one iteration count"),
        ([*arguments(data, random, out), "--iterations", "0", "5"], "must be positive"),
        ([*arguments(data, random, out), "--iterations", "20000"], "max_iterations"),
    ):
        assert SCRIPT.main(args) == 2, message
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and err.startswith("filter_residuals: error:") and message in err, err
    assert not out.exists()  # nothing written
