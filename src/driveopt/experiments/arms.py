"""What a bench episode runs and what its record says of where it ran: the registered planner with the bench
options applied (:func:`planner_spec`), and the provenance every record carries (:func:`provenance`). The one-by-one
loop (:mod:`driveopt.experiments.bench`) and the lock-step loop (:mod:`driveopt.experiments.lockstep`) both use them."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from driveopt.drivers.base import DriverSpec, with_samples_and_config
from driveopt.experiments.runner import cpu_model, usable_cpus
from driveopt.registry import get_planner
from driveopt.solve_export import source_digest

CODE_DIGITS = 16  # hex digits of the source digest a record keeps


def provenance() -> dict[str, Any]:
    """Where an episode planned, on how many CPUs (the worker's share, see driveopt.experiments.runner) of which model:
    its plan_ms are theirs; and which driveopt sources and jax and numpy versions ran it, so that records of other code
    are told apart."""
    return {"device": jax.default_backend(), "cpus": len(usable_cpus()), "cpu_model": cpu_model(),
            "code": source_digest()[:CODE_DIGITS], "jax": jax.__version__, "numpy": np.__version__}


def planner_spec(name: str, options: dict[str, Any]) -> DriverSpec:
    """The registered planner ``name`` with the bench options (samples, weights, config, replan_every, latency) applied."""
    samples = options.get("samples")
    spec = with_samples_and_config(get_planner(name).with_weights(options.get("weights")),
                                   int(samples) if samples else None, options.get("config", {}))
    spec = spec.with_replan_every(options.get("replan_every"))
    return spec.with_latency(options.get("latency"))
