"""benchmarks/perf/op_count.py: operations counted by kind on a jaxpr, loops times their length, while loops refused."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import pytest

from benchmarks.perf import op_count


def count(fn, *args):
    return op_count.count_operations(jax.make_jaxpr(fn)(*args))


def test_a_product_counts_a_multiply_and_an_add_per_term():
    a, b = jnp.ones((7, 5)), jnp.ones((5, 3))
    assert count(lambda a, b: a @ b, a, b) == {"products": 2 * 7 * 3 * 5, "total": 2 * 7 * 3 * 5}


def test_elementwise_counts_outputs_and_data_movement_counts_nothing():
    x = jnp.ones((4, 6))
    counts = count(lambda x: jnp.sqrt(x * 2.0 + 1.0).T.reshape(-1)[:10], x)
    assert counts == {"elementwise": 3 * 24, "total": 3 * 24}
    assert count(lambda x: jnp.sum(x, axis=1), x) == {"reductions": 24, "total": 24}


def test_a_scan_counts_its_body_times_its_length_and_a_call_what_it_runs():
    x = jnp.ones((8,))
    body = lambda c, _: (c * 2.0 + 1.0, None)  # noqa: E731
    scanned = count(lambda x: jax.lax.scan(body, x, None, length=5)[0], x)
    assert scanned == {"elementwise": 5 * 2 * 8, "total": 80}
    assert count(jax.jit(lambda x: x + 1.0), x) == {"elementwise": 8, "total": 8}
    branches = count(lambda x: jax.lax.cond(x[0] > 0, lambda x: x * 2.0, lambda x: jnp.exp(x) + x, x), x)
    assert branches["elementwise"] == 1 + 2 * 8  # the comparison, then the costlier branch


def test_a_while_loop_is_refused():
    fn = lambda x: jax.lax.while_loop(lambda c: c[0] < 3.0, lambda c: c + 1.0, x)  # noqa: E731
    with pytest.raises(ValueError, match="while_loop"):
        count(fn, jnp.zeros(2))


def test_the_projection_counts_from_the_command_line_match_the_products_closed_form(tmp_path):
    """Per row and iteration, the projection's products are both axes' maps to the K nodes' positions and the P velocity
    and acceleration rows and back (2 x 2 x 11 (K + 2P) each way) plus the solve and the penalty (2 x 2 x 11 x 11 each):
    P = 100 nodes plainly, 37 control points on 4 pieces. Written to --json with the command."""
    out = tmp_path / "counts.json"
    assert op_count.main(["--samples", "8", "--iterations", "1", "--projection-iterations", "2",
                          "--set", "derivative_bounds=control_points", "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    for side, rows in (("plain", 100), ("changed", 37)):
        assert record[side]["per_row_and_iteration"]["products"] == 2 * 2 * 11 * (100 + 2 * rows) * 2 + 2 * 2 * 11 * 11 * 2
    assert record["changed"]["settings"] == {"derivative_bounds": "control_points"}
    assert record["changed"]["per_call"]["total"] < record["plain"]["per_call"]["total"]
