"""The exported solve: a later process loads the lowered planner instead of tracing it, with the same results; a
damaged file is exported again; what the key does not cover is never exported."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from driveopt import solve_export
from driveopt.method import Method
from driveopt.planner import compiled_solve, exported_solve, solve
from driveopt.problem import build_problem
from driveopt.ranking import FeasibilityFirst
from driveopt.sampler import GaussianPrior
from driveopt.scene import load_scene
from driveopt.solve_export import ExportedCalls, ExportWarning, graph_key

TINY = dict(sampler=dict(num_samples=19, num_iterations=1, num_constraint_elites=8, num_elites=4),
            projection=dict(max_iterations=2))  # 19 samples: a graph no other test compiles; one iteration: a small one


@pytest.fixture(scope="module")
def inputs(small_config):
    config = small_config.replace(**TINY)
    problem = build_problem(load_scene("dense-snapshot"), config.basis, max_obstacles=1)  # a smaller graph: compiles faster
    return problem, GaussianPrior.from_config(config.sampler, config.projection.v_max), config


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """Exports into ``tmp_path``, with this module's functions trusted as driveopt's own."""
    monkeypatch.setattr(solve_export, "export_folder", lambda: tmp_path)
    monkeypatch.setattr(solve_export, "TRUSTED_MODULES", (*solve_export.TRUSTED_MODULES, __name__.split(".")[0]))
    return tmp_path


def traced_solve(traces):
    """solve, counting its traces in ``traces``."""

    def counted(*args, **kwargs):
        traces.append(1)
        return solve(*args, **kwargs)

    counted.__qualname__ = "traced_solve.counted"
    return counted


def like_plan(fun):
    """``fun`` through exported graphs as plan() runs solve."""
    return ExportedCalls(fun, exported_solve().static_argnames, exported_solve().jit_options)


def run(calls, inputs, seed=0):
    problem, prior, config = inputs
    return jax.device_get(calls(problem, jax.random.PRNGKey(seed), prior=prior, config=config))


def assert_same(a, b):
    jax.tree_util.tree_map(np.testing.assert_array_equal, a, b)


@pytest.mark.slow  # suite time: run with -m slow
def test_a_new_process_loads_the_graph_without_tracing_and_gets_the_same_results(inputs, folder):
    traces = []
    first = like_plan(traced_solve(traces))
    result = run(first, inputs)
    assert len(traces) == 1 and len(list(folder.glob("*.export"))) == 1
    run(first, inputs, seed=1)
    assert len(traces) == 1  # one graph per process

    later = like_plan(traced_solve(traces))  # what a second process builds
    again = run(later, inputs)
    assert len(traces) == 1  # loaded from the file, not traced
    assert_same(again, result)
    problem, prior, config = inputs  # and what the plain jit computes
    assert_same(result, jax.device_get(compiled_solve()(problem, jax.random.PRNGKey(0), config, prior)))


def double(x):
    return 2 * x


def test_a_damaged_file_is_exported_again_and_replaced(folder):
    traces = []

    def counted(x):
        traces.append(1)
        return double(x)

    calls = lambda: ExportedCalls(counted, (), {})  # noqa: E731 - what each new process builds
    np.testing.assert_array_equal(calls()(jnp.ones(3)), 2 * np.ones(3))
    (path,) = folder.glob("*.export")
    path.write_bytes(b"not an exported graph")
    np.testing.assert_array_equal(calls()(jnp.ones(3)), 2 * np.ones(3))
    assert len(traces) == 2 and path.stat().st_size > 100
    np.testing.assert_array_equal(calls()(jnp.ones(3)), 2 * np.ones(3))
    assert len(traces) == 2  # the replaced file loads


def test_the_key_names_what_shapes_the_graph(inputs):
    problem, prior, config = inputs

    def key(config=config, samples=None, ranking=FeasibilityFirst(), tree=(problem, prior)):
        leaves, in_tree = jax.tree_util.tree_flatten(tree)
        avals = tuple(map(jax.typeof, leaves))
        if samples is not None:
            avals = avals[:-1] + (jax.core.ShapedArray((samples,), jnp.float32),)
        return graph_key(solve, {"config": config, "method": Method(ranking=ranking)}, in_tree, avals)

    assert key() == key() and len(key()) == 40
    assert key(config=config.replace(projection={"max_iterations": 4})) != key()  # a static argument
    assert key(ranking=FeasibilityFirst(2.0)) != key()  # a strategy inside the method
    assert key(samples=7) != key()  # an argument's shape
    assert key(tree=(problem, prior, None)) != key()  # the arguments' structure

    class UserRanking(FeasibilityFirst):  # a user's strategy (in a driveopt Method): its code is not in the key, so it
        # is never exported
        pass

    assert key(ranking=UserRanking()) is None
    assert graph_key(lambda x: x, {}, jax.tree_util.tree_structure((1.0,)), (jax.typeof(1.0),)) is None  # a user's function


def test_what_cannot_be_exported_runs_as_a_plain_jit_with_one_warning(folder):
    def host_sum(x, scale):  # a host callback: jax.export refuses it
        return jax.pure_callback(lambda v: np.asarray(v.sum() * scale, np.float32), jax.ShapeDtypeStruct((), jnp.float32), x)

    calls = ExportedCalls(host_sum, ("scale",), {})
    with pytest.warns(ExportWarning, match="not exported"):
        assert float(calls(jnp.arange(4.0), scale=2.0)) == 12.0
    assert float(calls(jnp.arange(5.0), scale=2.0)) == 20.0  # another shape: another graph, plain again
    assert list(folder.iterdir()) == []


def test_without_the_compilation_cache_nothing_is_exported(folder, monkeypatch):
    monkeypatch.setattr(solve_export, "export_folder", lambda: None)
    traces = []
    for _ in range(2):  # two processes: each traces its own function

        def counted(x):
            traces.append(1)
            return double(x)

        np.testing.assert_array_equal(ExportedCalls(counted, (), {})(jnp.ones(3)), 2 * np.ones(3))
    assert len(traces) == 2 and list(folder.iterdir()) == []


def test_the_folder_keeps_the_most_recent_files(folder, monkeypatch):
    monkeypatch.setattr(solve_export, "MAX_FILES", 2)
    calls = ExportedCalls(double, (), {})
    for n in range(1, 5):
        np.testing.assert_array_equal(calls(jnp.ones(n)), 2 * np.ones(n))
    assert len(list(folder.glob("*.export"))) == 2
