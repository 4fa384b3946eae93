"""benchmarks/perf/call_profile.py: its separately jitted parts are the planner's first iteration, and a profile records
every part with its share of the call."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt.fallback import Fallback
from driveopt.method import Method
from driveopt.planner import compiled_solve
from driveopt.problem import build_problem
from driveopt.ranking import FeasibilityFirst
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene

from benchmarks.perf import call_profile


def test_the_parts_reproduce_the_planners_first_iteration():
    cfg = call_profile.profile_config(24, iterations=2, projection_iterations=4)
    problem = build_problem(load_scene(call_profile.PROBLEM), cfg.basis)
    prior, ranking, fallback = GaussianPrior.from_config(cfg.sampler, cfg.projection.v_max), FeasibilityFirst(), Fallback()
    key = jax.random.PRNGKey(3)
    pipeline = call_profile.Pipeline(cfg, problem, prior, ranking, fallback, key)
    first = compiled_solve()(problem, key, cfg, prior, None, None, None, method=Method(ranking, fallback)).first
    assert pipeline.rows.shape == (24 + 2, 8) and pipeline.runs["projection"] == 2 and pipeline.runs["proposal_next"] == 1
    np.testing.assert_array_equal(pipeline.rows, first.setpoints)
    np.testing.assert_allclose(pipeline.qp_coeffs, first.qp_coeffs, rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(pipeline.projected.coeffs, first.projected_coeffs, rtol=1e-4, atol=1e-2)
    np.testing.assert_allclose(pipeline.projected.residuals.total, first.residual, rtol=1e-3, atol=1e-4)
    np.testing.assert_array_equal(np.sort(pipeline.ranked[0]), np.sort(first.elite_index))


def test_a_profile_is_written_with_every_part(tmp_path):
    out = tmp_path / "profile.json"
    # the first test's configuration: its compiled planner is reused
    assert call_profile.main(["--json", str(out), "--samples", "24", "--calls", "2", "--iterations", "2",
                              "--projection-iterations", "4"]) == 0
    report = json.loads(out.read_text())
    assert len(report["load_before"]) == 3 and len(report["load_after"]) == 3 and report["machine"]["cpus"] >= 1
    (result,) = report["results"]
    assert list(result["parts_ms"]) == list(call_profile.PARTS)
    assert all(v > 0 for v in result["parts_ms"].values())
    assert result["parts_sum_ms"] == pytest.approx(sum(result["parts_ms"].values()))
    assert sum(result["share_of_parts"].values()) == pytest.approx(1.0)
    assert result["pieces"]["setpoint_qp"]["runs_per_call"] == 2 and result["pieces"]["fallback"]["runs_per_call"] == 1
    assert all(piece["compile_s"] > 0 for piece in result["pieces"].values())  # each timed before its first run
    assert result["whole_ms"] > 0 and result["plan_ms"] > 0 and result["whole_compile_s"] > 0
    assert result["projection_iterations_run"] == 4 and result["batch_rows"] == 26
    operations, per_call = result["projection_operations"], result["projection_operations_per_call"]
    assert operations["products"] > 0 and per_call["total"] == 2 * operations["total"]
    assert result["projection_gops_per_s"] == pytest.approx(per_call["total"] / result["parts_ms"]["projection"] / 1e6)


def test_the_projection_count_is_its_products_and_elementwise_work_per_iteration():
    """Each projection iteration adds the same work: its products are, per row, the (n, 3K) map to the nodes and the
    three (K, n) maps back of each axis, and the (n, n) solve and penalty (n = 11 coefficients, K = 100 nodes)."""
    rows, n, K = 24 + 2, 11, 100
    coeffs, boundary = jnp.zeros((rows, 2 * n)), jnp.zeros((rows, 3))
    counts = {}
    for iterations in (2, 3):
        cfg = call_profile.profile_config(24, iterations=1, projection_iterations=iterations)
        problem = build_problem(load_scene(call_profile.PROBLEM), cfg.basis)
        counts[iterations] = call_profile.projection_operations(problem, coeffs, boundary, boundary, cfg)
    step = {kind: counts[3][kind] - counts[2][kind] for kind in ("products", "elementwise", "total")}
    assert step["products"] == rows * 2 * 2 * (n * 3 * K + 3 * K * n + 2 * n * n)
    assert step["elementwise"] > rows * K * 10  # at least one operation per node of each of the ten neighbours
    assert step["total"] == sum(step[kind] for kind in ("products", "elementwise")) + (
        counts[3].get("reductions", 0) - counts[2].get("reductions", 0))
