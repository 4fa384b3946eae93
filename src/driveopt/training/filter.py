"""``driveopt train filter``: fit P2's learned safety filter (§III-C, eq. 9) through the unrolled projection, resumably.

Examples: the observations of the demonstration rows the harness learns from (:mod:`driveopt.training.harness`:
status SUCCESS, not within ``crash_margin`` seconds of a collision, canonical order, whole episodes held out or separate
validation files), each rebuilt into its planning problem (:func:`driveopt.data.replay.problem_from_row`). For every
observation ``samples`` set-points are drawn from the chosen prior (``samples_from``: the VQ-VAE as P2, the CVAE, or the
planner's Gaussian) and turned into trajectories xi by the planner's own set-point QP
(:func:`driveopt.planner.setpoint_batch`); the filter sets up their projection, which runs exactly ``unroll``
iterations (default 25; the authors: 5) of the planner's own code (:func:`driveopt.planner.project_batch` with
``unroll=True``), and the loss is P2 eq. 9, a mean over samples and observations::

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

Optimiser: AdamW with a step decay. Output folder, as the other trainers: ``last.ckpt`` (resume state), ``filter.ckpt``
(the best epoch by :func:`selection_key`: the most validation samples feasible, then the lowest validation loss; what
``--filter-weights`` and the ``vqvae-filter`` planner load) and ``history.json``, written atomically after every epoch;
``last.ckpt`` also every ``save_every`` seconds within an epoch (the steps done and their running sums: an epoch of
20 000 observations takes about an hour on 2 cores). Rerunning resumes, mid-epoch too: each step's minibatch and samples
follow from the seed, the epoch and the step, so a resumed run takes the same steps as an uninterrupted one. A
checkpoint from other data, another split, other settings, another prior or projection is refused with the reason;
settings are checked before the data is read, and a non-finite training loss stops with
:class:`~driveopt.training.harness.TrainingError`.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

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
from driveopt.learned.checkpoint import CheckpointError
from driveopt.planner import project_batch, setpoint_batch
from driveopt.problem import PlanningProblem
from driveopt.projection import constraint_residuals
from driveopt.qp import make_model
from driveopt.safety.learned import LearnedFilter
from driveopt.sim.scenarios import ScenarioError, get_scenario
from driveopt.training import harness

WEIGHTS = "filter.ckpt"  # the best epoch's weights in the output folder
SAMPLE_SOURCES = ("vqvae", "cvae", "gaussian")  # --samples-from
VALIDATION_KEY = 2**30  # folded into the run's key for the validation samples (epoch keys are 1, 2, ...)


@dataclasses.dataclass(frozen=True)
class TrainConfig(harness.BaseTrainConfig):
    """The filter's settings: the common ones (:class:`~driveopt.training.harness.BaseTrainConfig`; ``batch_size``
    counts observations), the samples and the unrolled projection."""

    epochs: int = 30  # [-]
    batch_size: int = 16  # [-] observations (demonstration rows) per step
    samples: int = 64  # [-] trajectories drawn from the prior per observation
    unroll: int = 25  # [-] projection iterations unrolled (the authors': 5; 25 is what the planner runs in P2 Fig. 8's target)
    residual_weight: float = 1000.0  # [m^2] s of eq. 9, per unit of total residual (m, m/s, m/s^2 summed, as ranked)
    samples_from: str = "vqvae"  # [-] the prior the samples come from: vqvae | cvae | gaussian

    OWN_SETTINGS_AFTER: ClassVar[str] = "batch_size"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("samples", "unroll"):
            check_count(self.setting_name(name), getattr(self, name), 1)
        check_number(self.setting_name("residual_weight"), self.residual_weight, 0.0, unit="m^2")
        if self.samples_from not in SAMPLE_SOURCES:
            raise ConfigError(f"{self.setting_name('samples_from')} must be one of {', '.join(SAMPLE_SOURCES)}, "
                              f"got {self.samples_from!r}")


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
def draw_setpoints(prior: Any, problems: PlanningProblem, keys: jax.Array, num: int) -> jnp.ndarray:
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
def _validation_terms(params, norm, problems, setpoints, cfg, config):
    return batch_terms(params, cfg, norm, problems, setpoints, config)


# ------------------------------------------------------------------------------------------- inputs


def training_config(config: PlannerConfig, tcfg: TrainConfig) -> PlannerConfig:
    """``config`` with ``tcfg.samples`` per batch, one sampler pass and ``tcfg.unroll`` projection iterations of P2's
    map: plain, the bounds at the nodes (the filter learns the map's parameters and start; a planner may accelerate
    the map and bound at the control points, as vqvae-filter does, and the shipped filters were trained so)."""
    return config.with_samples(tcfg.samples).replace(
        sampler={"num_iterations": 1},
        projection={"max_iterations": tcfg.unroll, "anderson_window": 0, "derivative_bounds": "nodes"})


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
    adapted = {name: adapt_to_vehicle(config, BicycleModel(acceleration_range=s.acceleration_range, steering_range=s.steering_range)) for name, s in scenarios.items()}
    if len(set(adapted.values())) > 1:
        raise DatasetError(f"the scenarios {names} have cars with other limits: train one filter per car")
    return next(iter(adapted.values())), {name: s.v_des for name, s in scenarios.items()}


def row_problems(data: Demonstrations, rows: np.ndarray, v_des: dict[str, float], config: PlannerConfig) -> PlanningProblem:
    """The planning problems of ``rows`` (:func:`~driveopt.data.replay.problem_from_row`), stacked (numpy, R leading)."""
    scenario = data.episodes["scenario"][data.episode[rows]]
    problems = [problem_from_row(data, int(r), v_des[str(s)], config.basis) for r, s in zip(rows, scenario)]
    return jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(x) for x in a]), *problems)


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


def training_split(data_paths: harness.Paths, validation_paths: harness.Paths | None, tcfg: TrainConfig,
                   cfg: fl.FilterConfig) -> harness.Split:
    """The harness's split (:func:`~driveopt.training.harness.load_split`); DatasetError when the demonstrations'
    plans have another number of coefficients than the filter's basis."""
    split = harness.load_split(data_paths, validation_paths, tcfg)
    if split.data.coeffs.shape[-1] != cfg.num_coeffs:
        raise DatasetError(f"the demonstrations' plans have {split.data.coeffs.shape[-1]} coefficients, the filter's basis "
                           f"{cfg.num_coeffs}")
    return split


def split_planner(split: harness.Split, config: PlannerConfig) -> tuple[PlannerConfig, dict[str, float]]:
    """(``config`` adapted to the car of the split's scenarios, their desired speeds [m/s] by scenario name)
    (:func:`scenario_config`); DatasetError when the validation rows' car has other limits than the training rows'."""
    planner, v_des = scenario_config(split.data, split.train_rows, config)
    if len(split.val_rows):
        held_planner, held_v_des = scenario_config(split.held, split.val_rows, config)
        if held_planner != planner:
            raise DatasetError("the validation demonstrations' car has other limits than the training demonstrations'")
        v_des = {**v_des, **held_v_des}
    return planner, v_des


@dataclasses.dataclass(frozen=True)
class FilterInputs:
    """What the filter learns from: the split, the planning configuration it trains in and the prior of the samples."""

    split: harness.Split
    lanes: list[int]  # lane counts of the training roads
    config: PlannerConfig  # the training's planning configuration (:func:`training_config`)
    prior: Any  # draws the samples (:func:`training_prior`)
    prior_record: dict[str, Any]  # names the prior in the checkpoints
    train_problems: PlanningProblem  # stacked (numpy, N leading): the training rows' problems
    val_problems: PlanningProblem | None  # those of the validation rows (None: no validation rows)


def filter_inputs(data_paths: harness.Paths, validation_paths: harness.Paths | None, cfg: fl.FilterConfig, tcfg: TrainConfig,
                  config: PlannerConfig, prior_weights: str | Path | None) -> FilterInputs:
    """The inputs of :func:`train_filter`, checked: ConfigError when the filter's basis is not the planner's (before
    any data is read), DatasetError or CheckpointError for unusable demonstrations or prior weights."""
    if cfg.basis != config.basis:
        raise ConfigError(f"the filter's basis {cfg.basis} is not the planner's {config.basis}")
    split = training_split(data_paths, validation_paths, tcfg, cfg)
    lanes = split.lanes()
    planner, v_des = split_planner(split, config)
    run_config = training_config(planner, tcfg)
    prior, prior_record = training_prior(tcfg.samples_from, lanes, run_config, prior_weights)
    train_problems = row_problems(split.data, split.train_rows, v_des, run_config)
    val_problems = row_problems(split.held, split.val_rows, v_des, run_config) if len(split.val_rows) else None
    return FilterInputs(split, lanes, run_config, prior, prior_record, train_problems, val_problems)


def check_resumable(path: Path, stored: dict[str, Any], meta: dict[str, Any], tcfg: TrainConfig) -> None:
    """CheckpointError unless the checkpoint's ``stored`` meta has ``meta``'s network configuration, prior,
    projection and data, and the same settings (:func:`~driveopt.training.harness.check_same_run`). A projection
    setting added since the checkpoint was written ran at its default, so it reads as that."""
    recorded = dict(stored)
    if isinstance(stored.get("projection"), dict):
        recorded["projection"] = {**dataclasses.asdict(ProjectionConfig()), **stored["projection"]}
    expected = {"config": ("network configuration", meta["config"]), "prior": ("prior", meta["prior"]),
                "projection": ("projection", meta["projection"])}
    harness.check_same_run(path, recorded, tcfg, meta["data"], expected)


def _take(problems: PlanningProblem, idx: np.ndarray) -> PlanningProblem:
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a[idx]), problems)


class Validation:
    """The validation observations with their samples, drawn once from the prior (the same for every epoch), and
    eq. 9's terms on them, evaluated ``chunk`` observations at a time."""

    def __init__(self, problems: PlanningProblem, prior: Any, key: jax.Array, tcfg: TrainConfig, cfg: fl.FilterConfig,
                 config: PlannerConfig, chunk: int) -> None:
        self.leaves, self.treedef = jax.tree_util.tree_flatten(problems)
        self.tcfg, self.cfg, self.config, self.chunk = tcfg, cfg, config, chunk
        keys = jax.random.split(key, len(self.leaves[0]))
        self.setpoints = np.concatenate(harness.chunks([*self.leaves, np.asarray(keys)], lambda *a: draw_setpoints(
            prior, self.problems(a[:-1]), a[-1], tcfg.samples), chunk))

    def problems(self, leaves: Any) -> PlanningProblem:
        return jax.tree_util.tree_unflatten(self.treedef, leaves)

    def terms(self, params: Any, normaliser: fl.Normaliser) -> dict[str, float]:
        """Means over observations and samples of the correction [m^2], residual and feasible share, and eq. 9's loss."""
        parts = harness.chunks([*self.leaves, self.setpoints], lambda *a: _validation_terms(
            params, normaliser, self.problems(a[:-1]), a[-1], self.cfg, self.config), self.chunk)
        terms = {k: float(np.mean(np.concatenate([part[k] for part in parts]))) for k in parts[0]}
        return {**terms, "loss": terms["correction"] + self.tcfg.residual_weight * terms["residual"]}

    def plain_filter_terms(self, params: Any, normaliser: fl.Normaliser) -> dict[str, float]:
        """:meth:`terms` of the plain filter (the configuration's gammas, the samples as first iterate, zero
        multipliers): the baseline the learned one is compared with."""
        projection = self.config.projection
        return self.terms(fl.plain_params(params, self.cfg, projection.gamma_obs, projection.gamma_lane), normaliser)


# ------------------------------------------------------------------------------------------- training


def selection_key(record: dict[str, Any]) -> tuple[float, float]:
    """How an epoch's history record ranks for ``filter.ckpt`` (higher is better): the share of validation samples
    feasible after the unrolled iterations, then the lower validation loss (without validation rows: the same on the
    training epoch). Eq. 9's loss can fall while that share falls (docs/findings/learned-filter.md, fifth round), and the share
    is what the planner's pick needs."""
    split = "val" if "val_feasible" in record else "train"
    return record[f"{split}_feasible"], -record[f"{split}_loss"]


def train_filter(
    data_paths: harness.Paths,
    out_dir: str | Path,
    cfg: fl.FilterConfig = fl.FilterConfig(),
    tcfg: TrainConfig = TrainConfig(),
    *,
    config: PlannerConfig,
    prior_weights: str | Path | None = None,
    validation_paths: harness.Paths | None = None,
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
    out = harness.check_output_folder(out_dir, WEIGHTS)
    inputs = filter_inputs(data_paths, validation_paths, cfg, tcfg, config, prior_weights)
    split = inputs.split
    meta = {"config": cfg.to_dict(), "train_config": tcfg.record(), "data": split.record(), "lanes": inputs.lanes,
            "prior": inputs.prior_record, "projection": dataclasses.asdict(inputs.config.projection), "rows": split.row_counts()}
    key = jax.random.PRNGKey(tcfg.seed)
    batch_size, steps = harness.epoch_steps(len(split.train_rows), tcfg.batch_size)
    optimiser = harness.make_optimiser(tcfg, steps)
    params = fl.init_params(cfg, jax.random.fold_in(key, 0))
    rows = split.train_rows
    normaliser = fl.fit_normaliser(split.data.observation[rows], split.data.init_y[rows, 0], split.data.coeffs[rows], cfg)
    run = harness.TrainingRun(out, fl.CHECKPOINT_KIND, WEIGHTS, meta)
    state = run.resume({"params": params, "normaliser": normaliser, "opt_state": optimiser.init(params)},
                       lambda path, stored: check_resumable(path, stored, meta, tcfg))
    trainer = FilterEpochs(cfg, tcfg, key, optimiser, state, inputs, batch_size, steps, run,
                           save_every=save_every, stop_after_steps=stop_after_steps)
    harness.run_epochs(run, trainer, tcfg, desc="train filter", progress=progress, stop_after=stop_after)
    return run.summary(kept=max(run.history, key=selection_key, default=None), baseline=trainer.baseline)


class FilterEpochs(harness.EpochTrainer):
    """The filter's epochs: minibatch steps of eq. 9 on fresh samples, saved every ``save_every`` seconds within an
    epoch; then eq. 9 on the fixed validation samples."""

    def __init__(self, cfg: fl.FilterConfig, tcfg: TrainConfig, key: jax.Array, optimiser: optax.GradientTransformation,
                 state: dict[str, Any], inputs: FilterInputs, batch_size: int, steps: int, run: harness.TrainingRun, *,
                 save_every: float, stop_after_steps: int | None) -> None:
        self.cfg, self.tcfg, self.key, self.optimiser, self.run = cfg, tcfg, key, optimiser, run
        self.params, self.opt_state = state["params"], state["opt_state"]
        self.normaliser = fl.Normaliser(*state["normaliser"])
        self.inputs, self.batch_size, self.steps = inputs, batch_size, steps
        self.weight = jnp.float32(tcfg.residual_weight)
        self.save_every, self.stop_after_steps = save_every, stop_after_steps
        self.partial = run.resumed.get("partial")  # {"epoch", "steps", "sums"} of an epoch a mid-epoch save left unfinished
        self.steps_run = 0  # minibatch steps taken in this call
        self.saved = time.perf_counter()  # [s] when last.ckpt was last written
        self.validation, self.baseline = None, None
        if inputs.val_problems is not None:
            self.validation = Validation(inputs.val_problems, inputs.prior, jax.random.fold_in(key, VALIDATION_KEY), tcfg, cfg,
                                         inputs.config, batch_size)
            self.baseline = self.validation.plain_filter_terms(self.params, self.normaliser)

    def train_epoch(self, epoch: int, show: Callable[[str], None]) -> dict[str, Any] | None:
        epoch_key = self.epoch_key(epoch)
        done, sums = self.resumed_progress(epoch)
        self.saved = time.perf_counter()
        for i, idx in enumerate(harness.minibatches(epoch_key, len(self.inputs.split.train_rows), self.batch_size, self.steps)):
            if i < done:
                continue
            self.train_step(idx, jax.random.fold_in(epoch_key, i + 1), sums)
            show(f"step {i + 1}/{self.steps} train {sums['loss'] / (i + 1):.2f}")
            self.steps_run += 1
            self.stopped = self.stop_after_steps is not None and self.steps_run >= self.stop_after_steps
            if i + 1 < self.steps and (self.stopped or time.perf_counter() - self.saved >= self.save_every):
                self.save_progress(epoch, i + 1, sums)
                if self.stopped:
                    return None
        record = {"epoch": epoch + 1, **harness.train_means(sums, self.steps)}
        if self.validation is not None:
            record.update({f"val_{k}": v for k, v in self.validation.terms(self.params, self.normaliser).items()})
        return record

    def resumed_progress(self, epoch: int) -> tuple[int, dict[str, float]]:
        """(steps already taken, their running sums) of epoch ``epoch``: those a mid-epoch save recorded when this is
        the epoch it left unfinished, else none."""
        sums = {"loss": 0.0, "correction": 0.0, "residual": 0.0, "feasible": 0.0}
        partial, self.partial = self.partial, None
        if partial is not None and partial.get("epoch") == epoch + 1:
            return int(partial["steps"]), {k: float(partial["sums"][k]) for k in sums}
        return 0, sums

    def train_step(self, idx: np.ndarray, step_key: jax.Array, sums: dict[str, float]) -> None:
        """One AdamW step of eq. 9 on the observations ``idx`` with samples drawn from ``step_key``."""
        problems = _take(self.inputs.train_problems, idx)
        setpoints = draw_setpoints(self.inputs.prior, problems, jax.random.split(step_key, len(idx)), self.tcfg.samples)
        (value, terms), grads = value_and_grad(self.params, self.normaliser, problems, setpoints, self.weight, self.cfg,
                                               self.inputs.config)
        self.params, self.opt_state = _update(self.params, grads, self.opt_state, self.optimiser)
        harness.accumulate(sums, value, terms)

    def save_progress(self, epoch: int, steps_done: int, sums: dict[str, float]) -> None:
        """Write last.ckpt inside epoch ``epoch``: the state after ``steps_done`` of its steps and their running sums."""
        self.run.save_last(self.training_state(), {"baseline": self.baseline,
                                                   "partial": {"epoch": epoch + 1, "steps": steps_done, "sums": sums}})
        self.saved = time.perf_counter()

    def best_rank(self, run: harness.TrainingRun) -> tuple[float, float] | None:
        """Recomputed from the resumed history (last.ckpt records no rank)."""
        return min(map(self.rank, run.history), default=None)

    def rank(self, record: dict[str, Any]) -> tuple[float, float]:
        """:func:`selection_key`, negated: lower is better."""
        feasible, negative_loss = selection_key(record)
        return -feasible, -negative_loss

    def weights_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser}

    def training_state(self) -> dict[str, Any]:
        return {"params": self.params, "normaliser": self.normaliser, "opt_state": self.opt_state}

    def weights_meta(self, run: harness.TrainingRun) -> dict[str, Any]:
        return {"baseline": self.baseline}

    def last_meta(self, run: harness.TrainingRun) -> dict[str, Any]:
        return {"baseline": self.baseline}

    def describe(self, record: dict[str, Any]) -> str:
        return f"train {record['train_loss']:.2f} val {record.get('val_loss', float('nan')):.2f}"
