"""Many planning calls as one: E problems (E episodes stepping in lock-step) solved by one compiled call.

    results = plan_many([Call(problem_0, key_0), Call(problem_1, key_1, warm_0, previous_1)], config, slots=4)
    solutions = solve_many(problems, keys, config, prior, warm_starts, previous)   # stacked pytrees, leading axis E

:func:`solve_many` is :func:`driveopt.planner.solve` mapped (``jax.vmap``) over stacked problems, keys, warm starts
and previous plans; the configuration, the prior, the safety filter, the method and the runtime fields are shared.
:func:`plan_many` is its host wrapper, as :func:`driveopt.planner.plan` is ``solve``'s: it checks every call as
``plan`` does, pads the batch to ``slots`` calls with copies of the first (their results are dropped), runs one
compiled call (one compilation per slot count: keep to a few fixed counts) and returns one :class:`PlanResult` per
call, with the meaning ``plan`` gives it. The problems must share their obstacle slot count (``build_problem``
pads neighbours to ``max_obstacles`` with a mask), and either all carry a previous plan (its placeholder included)
or none does.

A mapped call computes what the separate calls compute, but XLA may order the float32 sums of a batched program
differently (one slot runs ``plan`` itself, bit for bit): results agree with ``plan``'s to float32 rounding, and the sampler can amplify a last-bit difference
into another choice between near-equal candidates (tests/core/test_multi_plan.py states the tolerance).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from driveopt.config import PlannerConfig, split_runtime
from driveopt.filtering import SafetyFilter
from driveopt.host_copy import to_host
from driveopt.method import DRIVEOPT_METHOD, Method
from driveopt.planner import (
    _STATIC,
    PlanResult,
    PreviousPlan,
    Solution,
    WarmStart,
    _jit_options,
    check_call,
    plan,
    solution_result,
    solve,
)
from driveopt.problem import PlanningProblem
from driveopt.sampler import GaussianPrior, Prior
from driveopt.scene import ProblemError
from driveopt.solve_export import ExportedCalls


class Call(NamedTuple):
    """The per-episode inputs of one planning call (the arguments of :func:`driveopt.planner.plan` that differ between
    episodes): the problem, a PRNG key, the warm start (or None), the previous plan (or None) and ``x_offset`` [m]."""

    problem: PlanningProblem
    key: jax.Array
    warm_start: np.ndarray | WarmStart | None = None
    previous: PreviousPlan | None = None
    x_offset: float = 0.0


def solve_many(
    problems: PlanningProblem,
    keys: jax.Array,
    config: PlannerConfig,
    prior: Prior,
    warm_start: WarmStart | None = None,
    previous: PreviousPlan | None = None,
    safety_filter: SafetyFilter | None = None,
    unroll: bool = False,
    method: Method = DRIVEOPT_METHOD,
    runtime: Mapping[str, Mapping[str, jax.Array]] | None = None,
) -> Solution:
    """:func:`driveopt.planner.solve` over a leading axis E of ``problems``, ``keys``, ``warm_start`` and ``previous``
    (stacked pytrees; None: none for any call); ``prior``, ``safety_filter`` and ``runtime`` are shared. Returns the E
    solutions stacked. Pure: jit it with ``config``, ``unroll`` and ``method`` static."""

    def one(problem, key, warm, prev):
        return solve(problem, key, config, prior, warm, prev, safety_filter, unroll, method, runtime)

    return jax.vmap(one)(problems, keys, warm_start, previous)


@functools.cache
def exported_solve_many() -> ExportedCalls:
    """:func:`solve_many` as :func:`plan_many` runs it: jitted through exported graphs, as ``plan`` runs ``solve``."""
    return ExportedCalls(solve_many, _STATIC, _jit_options())


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *leaves: np.stack([np.asarray(leaf) for leaf in leaves]), *trees)


def _stack_keys(keys: Sequence[jax.Array]) -> jax.Array:
    kinds = {(str(getattr(key, "dtype", None)), tuple(np.shape(key))) for key in keys}
    if len(kinds) > 1:
        raise ProblemError(f"the calls' keys must be of one kind (all jax.random.PRNGKey or all jax.random.key), got "
                           f"{sorted(kinds)}")
    return jnp.stack(list(keys))


def plan_many(
    calls: Sequence[Call],
    config: PlannerConfig = PlannerConfig(),
    *,
    prior: Prior | None = None,
    safety_filter: SafetyFilter | None = None,
    method: Method = DRIVEOPT_METHOD,
    slots: int | None = None,
) -> list[PlanResult]:
    """Plan every call of ``calls`` in one compiled call; one :class:`PlanResult` per call, in order.

    Each call is checked as :func:`driveopt.planner.plan` checks its input (ProblemError, ConfigError). ``slots``
    (default: ``len(calls)``): the batch size compiled for, at least ``len(calls)``; the unused slots run copies of the
    first call and are dropped. ``prior``, ``safety_filter`` and ``method`` are shared, as in ``plan``. One slot is
    ``plan`` itself (the same compiled program, so the same result bit for bit).
    """
    if not calls:
        raise ProblemError("plan_many needs at least one call")
    slots = len(calls) if slots is None else slots
    if isinstance(slots, bool) or not isinstance(slots, int) or slots < len(calls):
        raise ProblemError(f"slots must be an integer >= the {len(calls)} calls, got {slots!r}")
    if slots == 1:
        (call,) = calls
        return [plan(call.problem, config, key=call.key, prior=prior, warm_start=call.warm_start, previous=call.previous,
                     safety_filter=safety_filter, method=method, x_offset=call.x_offset)]
    checked = [check_call(c.problem, config, c.key, c.warm_start, c.previous, c.x_offset) for c in calls]
    if len({c.previous is None for c in checked}) > 1:
        raise ProblemError("either every call carries a previous plan (PreviousPlan.absent() for none yet) or none does")
    if len({int(np.shape(c.problem.obstacle_x)[0]) for c in checked}) > 1:
        raise ProblemError("the calls' problems must have one obstacle slot count (build_problem's max_obstacles)")
    if prior is None:
        prior = GaussianPrior.from_config(config.sampler, config.projection.v_max)
    padded = checked + [checked[0]] * (slots - len(checked))
    previous = None if checked[0].previous is None else _stack([c.previous for c in padded])
    compiled_config, runtime = split_runtime(config)
    solutions = to_host(exported_solve_many()(
        _stack([c.problem for c in padded]), _stack_keys([c.key for c in padded]), prior=prior,
        warm_start=_stack([c.warm_start for c in padded]), previous=previous, safety_filter=safety_filter,
        config=compiled_config, method=method, runtime=runtime))
    return [solution_result(jax.tree_util.tree_map(lambda a, i=i: a[i], solutions), config, method, c)
            for i, c in enumerate(checked)]
