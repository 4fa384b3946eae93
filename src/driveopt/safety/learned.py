"""P2's learned safety filter as the planner's pytree: weights as leaves, configuration static; loading and shipped weights.

:class:`LearnedFilter` is what ``plan(..., safety_filter=...)`` / ``solve`` take: for every batch it
runs the network of :mod:`driveopt.learned.filter` on the observation and each set-point-QP
trajectory and returns the per-sample gammas, initial multipliers and first iterate of the
projection. Planners with equal configurations share one compilation whatever the weights.

Weights are one checkpoint (``driveopt train filter``: ``filter.ckpt``); it records the lane counts
of its training roads, and :func:`filter_for` refuses weights trained for another lane count.
Without weights for a road (they ship for two and four lanes) the ``vqvae-filter`` planner warns and projects with the
plain barrier filter of its configuration. Any optimiser takes a filter checkpoint through
``--filter-weights FILE`` (drive, bench, plan) or the ``--config`` section
``{"safety_filter": {"weights": FILE}}`` (:func:`split_filter_section`).

Flax is imported when weights are loaded or run, not with this module.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Mapping

from driveopt.checks import ConfigError
from driveopt.files import shipped_weights_file
from driveopt.filtering import FilterInit
from driveopt.problem import PlanningProblem
from driveopt.pytree import pytree_dataclass, static

SHIPPED = {2: "filter-two-lane.ckpt", 4: "filter-four-lane.ckpt"}  # lanes -> file in driveopt/weights
FILTER_SECTION = "safety_filter"  # --config section naming a filter checkpoint: {"safety_filter": {"weights": FILE}}


@pytree_dataclass
class LearnedFilter:
    """The learned safety filter (P2 §III-C): a :class:`~driveopt.filtering.SafetyFilter`."""

    params: Any
    normaliser: Any  # driveopt.learned.filter.Normaliser
    config: Any = static()  # driveopt.learned.filter.FilterConfig

    def initialise(self, problem: PlanningProblem, coeffs) -> FilterInit:
        from driveopt.learned.filter import initialise

        return initialise(self.params, self.config, self.normaliser, problem, coeffs)


def load_filter(path: str | Path, lanes: int | None = None) -> LearnedFilter:
    """The filter of the checkpoint ``path``; with ``lanes``, CheckpointError when it records that it was trained for
    roads with other lane counts."""
    from driveopt.learned.filter import load_filter as load

    cfg, params, normaliser, _ = load(path, lanes)
    return LearnedFilter(params, normaliser, cfg)


def shipped_weights(lanes: int) -> Path | None:
    """Path of the filter weights shipped for roads with ``lanes`` lanes, or None."""
    return shipped_weights_file(SHIPPED, lanes)


def filter_for(lanes: int, weights: str | Path | None) -> LearnedFilter | None:
    """The filter from ``weights`` (or the shipped weights for ``lanes``); None, with a notice, when there are none
    (the projection then runs as configured). A given but unusable file, or one trained for another lane count,
    raises CheckpointError."""
    path = Path(weights) if weights else shipped_weights(lanes)
    if path is None:
        warnings.warn(f"no safety-filter weights shipped for {lanes}-lane roads: projecting with the plain barrier "
                      "filter of the configuration instead", stacklevel=2)
        return None
    return load_filter(path, lanes=lanes)


def learned_filter(config: Any, lanes: int, weights: str | Path | None) -> LearnedFilter | None:
    """:func:`filter_for` as a registry filter factory, ``(config, lanes, weights) -> filter``: the planner's
    configuration is not needed, the network's is in the checkpoint."""
    return filter_for(lanes, weights)


def split_filter_section(overrides: Mapping[str, Any]) -> tuple[dict[str, Any], str | None]:
    """(planner-config overrides, filter weights file or None) of ``--config`` overrides whose optional
    ``safety_filter`` section is ``{"weights": FILE}``; ConfigError for any other content of that section."""
    rest = {k: v for k, v in overrides.items() if k != FILTER_SECTION}
    if FILTER_SECTION not in overrides:
        return rest, None
    section = overrides[FILTER_SECTION]
    if not isinstance(section, Mapping) or set(section) != {"weights"}:
        raise ConfigError(f"config section '{FILTER_SECTION}' must be {{\"weights\": FILE}}, got {section!r}")
    weights = section["weights"]
    if weights is not None and not (isinstance(weights, str) and weights):
        raise ConfigError(f"{FILTER_SECTION}.weights must be a checkpoint file name or null, got {weights!r}")
    return rest, weights
