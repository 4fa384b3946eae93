"""``driveopt train filter``: fit P2's learned safety filter (§III-C, eq. 9) through the unrolled projection, resumably.

Examples: the observations of the demonstration rows the CVAE learns from (status SUCCESS, not within
``crash_margin`` seconds of a collision; rows, canonical order and validation split of
:mod:`driveopt.training.cvae`), each rebuilt into its planning problem
(:func:`driveopt.data.replay.problem_from_row`). For every observation ``samples`` set-points are drawn
from the chosen prior (``samples_from``: the VQ-VAE as P2, the CVAE, or the planner's Gaussian) and
turned into trajectories xi by the planner's own set-point QP (:func:`driveopt.planner.setpoint_batch`);
the filter sets up their projection, which runs exactly ``unroll`` iterations (default 25; the authors: 5) of the
planner's own code (:func:`driveopt.planner.project_batch` with ``unroll=True``), and the loss is P2
eq. 9, a mean over samples and observations::

    L = |xi_bar* - xi|^2 + s * c(xi_bar*)

with ``|.|^2`` over the 2n coefficients [m^2] and ``c`` the total residual of the projected trajectory
against the plain constraints (gamma = 1: the safety bounds themselves, in the units the planner ranks
by; the barrier rows would reward gamma -> 1, their loosest form), ``s = residual_weight``.

The planning configuration is the one the filter is for (``config``, by default the ``vqvae-filter``
planner's), adapted to highway-env's car as in closed loop
(:func:`driveopt.drivers.optimiser.adapt_to_vehicle`), with ``samples`` per batch and ``unroll``
projection iterations; the planner may run more (``vqvae-filter``: 100). Validation draws its samples
once (fixed for every epoch) and also reports the plain filter on them (``baseline``: gammas 1,
the samples as first iterate, zero multipliers; ``val_feasible``: share of samples within the
planner's residual tolerance).

Optimiser: AdamW with a step decay. Output folder, as the other trainers: ``last.ckpt`` (resume
state), ``filter.ckpt`` (the best epoch by :func:`selection_key`: the most validation samples feasible, then
the lowest validation loss; what ``--filter-weights`` and the ``vqvae-filter`` planner load) and ``history.json``,
written atomically after every epoch; ``last.ckpt`` also every ``save_every`` seconds within an epoch (the steps
done and their running sums: an epoch of 20 000 observations takes about an hour on 2 cores). Rerunning resumes,
mid-epoch too: each step's minibatch and samples follow from the seed, the epoch and the step, so a resumed run
takes the same steps as an uninterrupted one. A checkpoint from other data, another split, other settings, another
prior or projection is refused with the reason; settings are checked before the data is read, and a non-finite
training loss stops with :class:`~driveopt.training.cvae.TrainingError`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from driveopt.checks import ConfigError, check_count, check_number
from driveopt.config import PlannerConfig, ProjectionConfig
from driveopt.data.demonstrations import DatasetError, Demonstrations
from driveopt.data.replay import problem_from_row
from driveopt.files import file_digest
from driveopt.learned import filter as fl
from driveopt.learned.checkpoint import CheckpointError, load_checkpoint, restore, save_checkpoint
from driveopt.planner import project_batch, setpoint_batch
from driveopt.problem import PlanningProblem
from driveopt.projection import constraint_residuals
from driveopt.qp import make_model
from driveopt.safety.learned import LearnedFilter
from driveopt.sim.scenarios import ScenarioError, get_scenario
from driveopt.training.cvae import (
    TrainingError,
    _check_same_data,
    _make_folder,
    _rows,
    check_output_folder,
    data_record,
    epoch_bar,
    minibatches,
    road_lanes,
)
from driveopt.training.vqvae import _chunks

SAMPLE_SOURCES = ("vqvae", "cvae", "gaussian")  # --samples-from


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    epochs: int = 30  # [-]
    batch_size: int = 16  # [-] observations (demonstration rows) per step
    samples: int = 64  # [-] trajectories drawn from the prior per observation
    unroll: int = 25  # [-] projection iterations unrolled (the authors': 5; 25 is what the planner runs in P2 Fig. 8's target)
    residual_weight: float = 1000.0  # [m^2] s of eq. 9, per unit of total residual (m, m/s, m/s^2 summed, as ranked)
    samples_from: str = "vqvae"  # [-] the prior the samples come from: vqvae | cvae | gaussian
    learning_rate: float = 1e-3  # [-] AdamW initial rate
    weight_decay: float = 6e-5  # [-]
    decay_every: int = 20  # [epochs] step decay period
    decay_factor: float = 0.1  # [-]
    validation_fraction: float = 0.1  # [-] share of episodes held out
    train_episodes: int = 0  # [-] learn from only this many of the other episodes (0: all)
    crash_margin: float = 3.0  # [s] rows this close before a collision are left out
    seed: int = 0  # [-] >= 0

    def __post_init__(self):
        for name, minimum in (("epochs", 1), ("batch_size", 1), ("samples", 1), ("unroll", 1), ("decay_every", 1),
                              ("train_episodes", 0), ("seed", 0)):
            check_count(f"TrainConfig.{name}", getattr(self, name), minimum)
        check_number("TrainConfig.residual_weight", self.residual_weight, 0.0, unit="m^2")
        check_number("TrainConfig.learning_rate", self.learning_rate, 0.0, low_open=True)
        check_number("TrainConfig.weight_decay", self.weight_decay, 0.0)
        check_number("TrainConfig.decay_factor", self.decay_factor, 0.0, 1.0, low_open=True)
        check_number("TrainConfig.validation_fraction", self.validation_fraction, 0.0, 1.0, high_open=True)
        check_number("TrainConfig.crash_margin", self.crash_margin, 0.0, unit="s")
        if self.samples_from not in SAMPLE_SOURCES:
            raise ConfigError(f"TrainConfig.samples_from must be one of {', '.join(SAMPLE_SOURCES)}, got {self.samples_from!r}")


# ------------------------------------------------------------------------------------------- the loss


def eq9_terms(params, cfg: fl.FilterConfig, norm: fl.Normaliser, problem: PlanningProblem, setpoints: jnp.ndarray,
              config: PlannerConfig) -> dict[str, jnp.ndarray]:
    """For one observation and its samples (S, 8): the mean over samples of the correction |xi_bar* - xi|^2 [m^2] and
    of the plain-constraint residual of xi_bar*, and the share of samples within the residual tolerance."""
    model = make_model(config.basis, config.qp)
    qp_coeffs, b_x, b_y = setpoint_batch(model, problem, config, setpoints)
    proj = project_batch(model, problem, config, qp_coeffs, b_x, b_y, LearnedFilter(params, norm, cfg), unroll=True)
    residual = constraint_residuals(model, problem, proj.coeffs, config.projection).total
    return {"correction": jnp.mean(jnp.sum((proj.coeffs - qp_coeffs) ** 2, axis=-1)), "residual": jnp.mean(residual),
            "feasible": jnp.mean(residual <= config.sampler.residual_tolerance)}


def batch_terms(params, cfg: fl.FilterConfig, norm: fl.Normaliser, problems: PlanningProblem, setpoints: jnp.ndarray,
                config: PlannerConfig) -> dict[str, jnp.ndarray]:
    """:func:`eq9_terms` of R observations (``problems`` stacked, ``setpoints`` (R, S, 8)), each (R,)."""
    return jax.vmap(lambda p, s: eq9_terms(params, cfg, norm, p, s, config))(problems, setpoints)


def loss(params, cfg: fl.FilterConfig, norm: fl.Normaliser, problems: PlanningProblem, setpoints: jnp.ndarray,
         config: PlannerConfig, residual_weight) -> tuple[jnp.ndarray, dict[str, jnp.ndarray]]:
    """P2 eq. 9, the mean over observations and samples: (loss, terms means)."""
    terms = {k: jnp.mean(v) for k, v in batch_terms(params, cfg, norm, problems, setpoints, config).items()}
    return terms["correction"] + residual_weight * terms["residual"], terms


# Jitted at module level, configurations static: trainings with equal settings share their compilations.


@functools.partial(jax.jit, static_argnames=("num",))
def _draw(prior: Any, problems: PlanningProblem, keys: jax.Array, num: int) -> jnp.ndarray:
    """(R, num, 8) set-points of the prior for each of R observations (the planner's first batch)."""
    return jax.vmap(lambda problem, key: prior.propose(problem, key, num, None).samples)(problems, keys)


@functools.partial(jax.jit, static_argnames=("cfg", "config"))
def value_and_grad(params, norm, problems, setpoints, residual_weight, cfg, config):
    """((loss, terms), gradient with respect to ``params``) of :func:`loss`, jitted (the training step's)."""
    return jax.value_and_grad(loss, has_aux=True)(params, cfg, norm, problems, setpoints, config, residual_weight)


@functools.partial(jax.jit, static_argnames=("optimiser",))
def _update(params, grads, opt_state, optimiser):
    updates, opt_state = optimiser.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


@functools.partial(jax.jit, static_argnames=("cfg", "config"))
def _terms(params, norm, problems, setpoints, cfg, config):
    return batch_terms(params, cfg, norm, problems, setpoints, config)


@functools.lru_cache(maxsize=16)  # one object per setting: the jitted step takes it as a static argument
def _optimiser(tcfg: TrainConfig, steps_per_epoch: int) -> optax.GradientTransformation:
    schedule = optax.exponential_decay(tcfg.learning_rate, transition_steps=tcfg.decay_every * steps_per_epoch,
                                       decay_rate=tcfg.decay_factor, staircase=True)
    return optax.adamw(schedule, weight_decay=tcfg.weight_decay)


# ------------------------------------------------------------------------------------------- inputs


def training_config(config: PlannerConfig, tcfg: TrainConfig) -> PlannerConfig:
    """``config`` with ``tcfg.samples`` per batch, one sampler pass and ``tcfg.unroll`` projection iterations."""
    return config.with_samples(tcfg.samples).replace(sampler={"num_iterations": 1}, projection={"max_iterations": tcfg.unroll})


def scenario_config(data: Demonstrations, rows: np.ndarray, config: PlannerConfig) -> tuple[PlannerConfig, dict[str, float]]:
    """(``config`` adapted to the car of the rows' scenarios, their desired speeds [m/s] by scenario name); DatasetError
    when a scenario is unknown or the scenarios' cars differ (one filter is trained for one projection)."""
    from driveopt.drivers.optimiser import adapt_to_vehicle
    from driveopt.sim.control import BicycleModel

    names = sorted({str(n) for n in data.episodes["scenario"][np.unique(data.episode[rows])]})
    try:
        scenarios = {name: get_scenario(name) for name in names}
    except ScenarioError as exc:
        raise DatasetError(f"demonstrations of a scenario whose road is unknown: {exc}") from None
    adapted = {name: adapt_to_vehicle(config, s, BicycleModel()) for name, s in scenarios.items()}
    if len(set(adapted.values())) > 1:
        raise DatasetError(f"the scenarios {names} have cars with other limits: train one filter per car")
    return next(iter(adapted.values())), {name: s.v_des for name, s in scenarios.items()}


def row_problems(data: Demonstrations, rows: np.ndarray, v_des: dict[str, float], config: PlannerConfig) -> PlanningProblem:
    """The planning problems of ``rows`` (:func:`~driveopt.data.replay.problem_from_row`), stacked (numpy, R leading)."""
    scenario = data.episodes["scenario"][data.episode[rows]]
    problems = [problem_from_row(data, int(r), v_des[str(s)], config.basis) for r, s in zip(rows, scenario)]
    return jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a]), *problems)


def _take(problems: PlanningProblem, idx: np.ndarray) -> PlanningProblem:
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a[idx]), problems)


def training_prior(samples_from: str, lanes: list[int], config: PlannerConfig, weights: str | Path | None) -> tuple[Any, dict]:
    """(prior, record) that draws the training samples: the VQ-VAE (PixelCNN checkpoint) or CVAE of ``weights``, by
    default the ones shipped for the road, or the planner's Gaussian. The record names it for resumption (a digest of
    the weights file). DatasetError when the rows span several lane counts (learned priors are per road),
    CheckpointError when there are no weights or they are unusable or for another road."""
    from driveopt.sampler import GaussianPrior

    v_max = config.projection.v_max
    if samples_from == "gaussian":
        if weights:
            raise ConfigError("--prior-weights is for --samples-from vqvae or cvae, not gaussian")
        return GaussianPrior.from_config(config.sampler, v_max), {"samples_from": "gaussian", "weights": None}
    if len(lanes) != 1:
        raise DatasetError(f"demonstrations of roads with {lanes} lanes: a learned prior is per lane count, give one road")
    if samples_from == "vqvae":
        from driveopt.priors.vqvae import load_prior, shipped_weights
    else:
        from driveopt.priors.cvae import load_prior, shipped_weights
    path = Path(weights) if weights else shipped_weights(lanes[0])
    if path is None:
        name, command = ("VQ-VAE", "driveopt train pixelcnn") if samples_from == "vqvae" else ("CVAE", "driveopt train cvae")
        raise CheckpointError(f"no {name} weights shipped for {lanes[0]}-lane roads: give --prior-weights "
                              f"(from {command}) or --samples-from gaussian")
    prior = load_prior(path, v_max, lanes=lanes[0])
    return prior, {"samples_from": samples_from, "weights": file_digest(path)}


def _check_resume(path: Path, meta: dict[str, Any], expected: dict[str, Any], tcfg: TrainConfig) -> None:
    """CheckpointError unless ``path``'s meta has ``expected``'s network configuration, prior, projection, data record
    and the same training settings (epochs aside)."""
    recorded = dict(meta)
    if isinstance(meta.get("projection"), dict):  # a setting added since it was written ran at its default, as before
        recorded["projection"] = {**dataclasses.asdict(ProjectionConfig()), **meta["projection"]}
    for key, what in (("config", "network configuration"), ("prior", "prior"), ("projection", "projection")):
        if recorded.get(key) != json.loads(json.dumps(expected[key])):
            raise CheckpointError(f"{path} was trained with another {what} ({meta.get(key)}, now {expected[key]}); use a new --out")
    stored = dict(meta.get("train_config", {}))
    mismatch = {k: (stored.get(k), v) for k, v in dataclasses.asdict(tcfg).items() if k != "epochs" and stored.get(k) != v}
    if mismatch:
        raise CheckpointError(f"{path} was trained with other settings {mismatch} (stored, now); use a new --out")
    _check_same_data(path, meta.get("data"), expected["data"])


# ------------------------------------------------------------------------------------------- training


def selection_key(record: dict[str, Any]) -> tuple[float, float]:
    """How an epoch's history record ranks for ``filter.ckpt`` (higher is better): the share of validation samples
    feasible after the unrolled iterations, then the lower validation loss (without validation rows: the same on the
    training epoch). Eq. 9's loss can fall while that share falls (docs/findings/learned-filter.md, fifth round), and the share
    is what the planner's pick needs."""
    split = "val" if "val_feasible" in record else "train"
    return record[f"{split}_feasible"], -record[f"{split}_loss"]


def train_filter(
    data_paths: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    cfg: fl.FilterConfig = fl.FilterConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    config: PlannerConfig,
    prior_weights: str | Path | None = None,
    validation_paths: str | Path | Sequence[str | Path] | None = None,
    progress: bool = True,
    save_every: float = 300.0,
    stop_after: int | None = None,
    stop_after_steps: int | None = None,
) -> dict[str, Any]:
    """Train (or resume training) the filter for the planning configuration ``config`` into ``out_dir``; returns a
    summary with the history. ``prior_weights``: checkpoint of the VQ-VAE (PixelCNN) or CVAE prior (default: the
    shipped one). ``save_every`` [s]: the period of mid-epoch saves of ``last.ckpt``. ``stop_after`` /
    ``stop_after_steps``: return after this many epochs / minibatch steps of this call, saved (for tests of
    resumption). The summary's ``weights`` is the path of ``filter.ckpt``, or None before an epoch wrote it."""
    out = check_output_folder(out_dir, "filter.ckpt")
    if cfg.basis != config.basis:
        raise ConfigError(f"the filter's basis {cfg.basis} is not the planner's {config.basis}")
    data, held, train_rows, val_rows = _rows(data_paths, validation_paths, tcfg)
    if data.coeffs.shape[-1] != cfg.num_coeffs:
        raise DatasetError(f"the demonstrations' plans have {data.coeffs.shape[-1]} coefficients, the filter's basis "
                           f"{cfg.num_coeffs}")
    lanes = road_lanes(data, train_rows)
    planner, v_des = scenario_config(data, train_rows, config)
    if len(val_rows):
        held_planner, held_v_des = scenario_config(held, val_rows, config)
        if held_planner != planner:
            raise DatasetError("the validation demonstrations' car has other limits than the training demonstrations'")
        v_des = {**v_des, **held_v_des}
    run_config = training_config(planner, tcfg)
    prior, prior_record = training_prior(tcfg.samples_from, lanes, run_config, prior_weights)
    train_problems = row_problems(data, train_rows, v_des, run_config)
    val_problems = row_problems(held, val_rows, v_des, run_config) if len(val_rows) else None

    batch_size = min(tcfg.batch_size, len(train_rows))
    steps_per_epoch = len(train_rows) // batch_size
    optimiser = _optimiser(tcfg, steps_per_epoch)
    meta_base = {"config": cfg.to_dict(), "train_config": dataclasses.asdict(tcfg), "data": data_record(data, held, val_rows),
                 "lanes": lanes, "prior": prior_record, "projection": dataclasses.asdict(run_config.projection),
                 "rows": {"train": int(len(train_rows)), "validation": int(len(val_rows))}}

    key = jax.random.PRNGKey(tcfg.seed)
    params = fl.init_params(cfg, jax.random.fold_in(key, 0))
    normaliser = fl.fit_normaliser(data.observation[train_rows], data.init_y[train_rows, 0], data.coeffs[train_rows], cfg)
    opt_state = optimiser.init(params)
    history: list[dict[str, Any]] = []
    partial = None  # {"epoch", "steps", "sums"} of an epoch that a mid-epoch save left unfinished
    last = out / "last.ckpt"
    if last.exists():
        meta, state = load_checkpoint(last, fl.CHECKPOINT_KIND)
        _check_resume(last, meta, meta_base, tcfg)
        target = {"params": params, "normaliser": normaliser, "opt_state": opt_state}
        restored = restore(target, {k: state.get(k) for k in target}, last, "the training state")
        params, normaliser, opt_state = restored["params"], fl.Normaliser(*restored["normaliser"]), restored["opt_state"]
        history = list(meta.get("history", []))
        partial = meta.get("partial")
    _make_folder(out)

    validate, baseline = None, None
    if val_problems is not None:  # the same samples every epoch
        val_keys = jax.random.split(jax.random.fold_in(key, 2**30), len(val_rows))
        leaves, treedef = jax.tree_util.tree_flatten(val_problems)
        val_setpoints = np.concatenate(_chunks([*leaves, np.asarray(val_keys)], lambda *a: _draw(
            prior, jax.tree_util.tree_unflatten(treedef, a[:-1]), a[-1], tcfg.samples), batch_size))

        def validate(p):
            parts = _chunks([*leaves, val_setpoints], lambda *a: _terms(
                p, normaliser, jax.tree_util.tree_unflatten(treedef, a[:-1]), a[-1], cfg, run_config), batch_size)
            terms = {k: float(np.mean(np.concatenate([part[k] for part in parts]))) for k in parts[0]}
            return {**terms, "loss": terms["correction"] + tcfg.residual_weight * terms["residual"]}

        baseline = validate(fl.plain_params(params, cfg, run_config.projection.gamma_obs, run_config.projection.gamma_lane))

    weight = jnp.float32(tcfg.residual_weight)
    best = max(map(selection_key, history), default=None)
    bar = epoch_bar(len(history), tcfg, stop_after, "train filter", progress)
    start = saved = time.perf_counter()
    steps_run, stopped = 0, False
    for epoch in bar:
        epoch_key = jax.random.fold_in(key, epoch + 1)
        sums = {"loss": 0.0, "correction": 0.0, "residual": 0.0, "feasible": 0.0}
        done = 0
        if partial is not None and partial.get("epoch") == epoch + 1:  # resume inside this epoch
            done, sums = int(partial["steps"]), {k: float(partial["sums"][k]) for k in sums}
        partial = None
        for i, idx in enumerate(minibatches(epoch_key, len(train_rows), batch_size, steps_per_epoch)):
            if i < done:
                continue
            problems = _take(train_problems, idx)
            setpoints = _draw(prior, problems, jax.random.split(jax.random.fold_in(epoch_key, i + 1), len(idx)), tcfg.samples)
            (value, terms), grads = value_and_grad(params, normaliser, problems, setpoints, weight, cfg, run_config)
            params, opt_state = _update(params, grads, opt_state, optimiser)
            sums["loss"] += float(value)
            for k in ("correction", "residual", "feasible"):
                sums[k] += float(terms[k])
            bar.set_postfix_str(f"step {i + 1}/{steps_per_epoch} train {sums['loss'] / (i + 1):.2f}")
            steps_run += 1
            stopped = stop_after_steps is not None and steps_run >= stop_after_steps
            if i + 1 < steps_per_epoch and (stopped or time.perf_counter() - saved >= save_every):
                save_checkpoint(last, fl.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser, "opt_state": opt_state},
                                {**meta_base, "epoch": epoch, "history": history, "baseline": baseline,
                                 "partial": {"epoch": epoch + 1, "steps": i + 1, "sums": sums}})
                saved = time.perf_counter()
                if stopped:
                    break
        if stopped and i + 1 < steps_per_epoch:
            break
        record = {"epoch": epoch + 1, **{f"train_{k}": v / steps_per_epoch for k, v in sums.items()}}
        if not math.isfinite(record["train_loss"]):
            raise TrainingError(f"training diverged in epoch {epoch + 1} (train loss {record['train_loss']}): "
                                f"lower the learning rate (now {tcfg.learning_rate:g})")
        if validate is not None:
            record.update({f"val_{k}": v for k, v in validate(params).items()})
        history.append(record)
        meta = {**meta_base, "epoch": epoch + 1, "history": history, "baseline": baseline}
        if best is None or selection_key(record) > best:
            best = selection_key(record)
            save_checkpoint(out / "filter.ckpt", fl.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser}, meta)
        save_checkpoint(last, fl.CHECKPOINT_KIND, {"params": params, "normaliser": normaliser, "opt_state": opt_state}, meta)
        saved = time.perf_counter()
        (out / "history.json").write_text(json.dumps(history, indent=1))
        bar.set_postfix_str(f"train {record['train_loss']:.2f} val {record.get('val_loss', float('nan')):.2f}")
        if stopped:
            break
    bar.close()
    weights = out / "filter.ckpt"
    return {"epochs": len(history), "history": history, "kept": max(history, key=selection_key, default=None),
            "baseline": baseline, "rows": meta_base["rows"],
            "seconds": time.perf_counter() - start, "out": str(out), "weights": str(weights) if weights.exists() else None}
