"""A result copied to the host in one buffer per dtype is the same, bit for bit and shape for shape, as jax.device_get's
copy of each array; on the CPU to_host copies each array (the packing is for accelerators)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt import host_copy
from driveopt.host_copy import to_host
from driveopt.planner import solve
from driveopt.problem import build_problem
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene


def assert_identical(got, expected):
    got_leaves, got_def = jax.tree_util.tree_flatten(got)
    expected_leaves, expected_def = jax.tree_util.tree_flatten(expected)
    assert got_def == expected_def
    for a, b in zip(got_leaves, expected_leaves):
        assert isinstance(a, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
        assert a.tobytes() == b.tobytes()  # the same bits: NaN and -0.0 included


def test_mixed_dtypes_shapes_and_keys_come_back_as_device_get_copies_them():
    tree = {"scalar": jnp.float32(-0.0), "matrix": jnp.arange(12, dtype=jnp.float32).reshape(3, 4) / 7,
            "nan": jnp.array([np.nan, np.inf, -1.5], jnp.float32), "flags": jnp.array([True, False, True]),
            "count": jnp.int32(7), "steps": jnp.arange(5, dtype=jnp.int32), "empty": jnp.zeros((0, 3), jnp.float32),
            "nested": (jnp.ones((2, 1, 2), jnp.float32), jnp.uint32(3)), "key": jax.random.key(1), "plain": 2.5}
    copied = to_host(tree, packed=True)
    expected = jax.device_get(tree)
    key, expected_key = copied.pop("key"), expected.pop("key")
    assert jnp.array_equal(jax.random.key_data(key), jax.random.key_data(expected_key))
    assert copied.pop("plain") == expected.pop("plain") == 2.5
    assert_identical(copied, expected)


def test_a_planning_calls_result_comes_back_as_device_get_copies_it(small_config):
    config = small_config.replace(sampler=dict(num_samples=16, num_iterations=1, num_constraint_elites=8, num_elites=4))
    problem = build_problem(load_scene("dense-snapshot"), config.basis, max_obstacles=1)
    prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    shapes = jax.eval_shape(lambda key: solve(problem, key, config, prior), jax.random.PRNGKey(0))  # traced, not compiled
    leaves, treedef = jax.tree_util.tree_flatten(shapes)
    assert len(leaves) > 20 and len({leaf.dtype for leaf in leaves}) >= 3
    rng = np.random.default_rng(0)
    values = [jnp.asarray((rng.normal(size=leaf.shape) * 100).astype(leaf.dtype)) for leaf in leaves]
    solution = jax.tree_util.tree_unflatten(treedef, values)
    assert_identical(to_host(solution, packed=True), jax.device_get(solution))


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the arrays of this test must live on the CPU")
def test_on_the_cpu_each_array_is_copied_on_its_own(monkeypatch):
    def refuse(arrays):
        raise AssertionError("packed on the CPU")

    monkeypatch.setattr(host_copy, "_pack", refuse)
    assert_identical(to_host({"a": jnp.ones(3), "b": jnp.int32(1)}), {"a": np.ones(3, np.float32), "b": np.int32(1)})
    with pytest.raises(AssertionError, match="packed on the CPU"):
        to_host({"a": jnp.ones(3), "b": jnp.int32(1)}, packed=True)
