"""The learned components, one row each: where a kind's trainer, command line, checkpoint loader, planner prior or
safety filter and shipped weights live.

The commands that treat every learned kind alike iterate :data:`KINDS` instead of naming them: ``driveopt train``
registers each row's subcommands (and lists them in its help), ``driveopt plot-prior`` draws a column and takes a
weights option for every row with a ``weights_option``, and so does :mod:`driveopt.experiments.prior_metrics`. A new
learned prior is its own modules plus one row here.

A row names code by import string (``"module:attribute"``) and :func:`resolve` imports it on demand, so importing
this table costs nothing: ``driveopt --help`` and the listings load neither JAX nor Flax. The signatures a consumer
relies on are those of the fields' comments.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any


class KindError(LookupError):
    """An unknown learned kind, or a row whose import string names nothing."""


@dataclass(frozen=True)
class LearnedKind:
    """One learned component: its ``driveopt train`` subcommands and the code behind them, and what the planners and
    the offline comparisons of the priors need from it. Empty strings: the kind has no such part. The ``rl`` row's
    two policies ship per algorithm as well as per road (:func:`driveopt.rl.policy.shipped_policy`), which is not
    ``shipped``'s signature: its ``shipped`` is empty."""

    name: str  # the kind's key, e.g. "cvae"
    title: str  # how figures and notices name it, e.g. "CVAE"
    train: tuple[str, ...]  # its `driveopt train` subcommands, in the order they are listed
    train_cli: str  # (model subparsers) -> None: adds the subcommands of ``train`` to `driveopt train`
    trainers: tuple[str, ...]  # the training entry point each subcommand of ``train`` runs
    loader: str  # reads the kind's checkpoint (the network's configuration and weights)
    shipped: str = ""  # (lanes) -> Path | None: the weights shipped in driveopt/weights for roads of that many lanes
    prior: str = ""  # (path, v_max, *, lanes) -> Prior: the planner's prior of a checkpoint (CheckpointError when unusable)
    prior_factory: str = ""  # (*options) -> ((config, lanes, weights) -> Prior): the registry's prior factory
    filter_factory: str = ""  # (config, lanes, weights) -> SafetyFilter | None: the registry's filter factory
    weights_option: str = ""  # its checkpoint option in plot-prior and the prior metrics ("": not compared offline)
    weights_aliases: tuple[str, ...] = ()  # other spellings plot-prior accepts for ``weights_option``
    checkpoint: str = ""  # what ``weights_option`` names, for the options' help

    @property
    def offline(self) -> bool:
        """Whether plot-prior draws this kind's prior and the prior metrics measure it (it has a ``weights_option``)."""
        return bool(self.weights_option)

    @property
    def weights_dest(self) -> str:
        """The argparse attribute of the weights option: named after its last spelling (``weights`` for the CVAE's
        ``--cvae-weights, --weights``)."""
        return (self.weights_aliases or (self.weights_option,))[-1].lstrip("-").replace("-", "_")

    def load_prior(self, path: Any, v_max: float, lanes: int | None = None) -> Any:
        """The planner's prior of the checkpoint ``path`` (:attr:`prior`)."""
        return resolve(self.prior)(path, v_max, lanes=lanes)

    def shipped_weights(self, lanes: int) -> Any:
        """The weights shipped for roads with ``lanes`` lanes, or None (:attr:`shipped`)."""
        return resolve(self.shipped)(lanes) if self.shipped else None


KINDS: tuple[LearnedKind, ...] = (
    LearnedKind(
        "cvae", "CVAE", ("cvae",), "driveopt.cli.train_cvae:register_models", ("driveopt.training.cvae:train_cvae",),
        "driveopt.learned.cvae:load_cvae", shipped="driveopt.priors.cvae:shipped_weights",
        prior="driveopt.priors.cvae:load_prior", prior_factory="driveopt.priors.cvae:cvae_prior",
        weights_option="--cvae-weights", weights_aliases=("--weights",), checkpoint="CVAE checkpoint"),
    LearnedKind(
        "vqvae", "VQ-VAE + PixelCNN", ("vqvae", "pixelcnn"), "driveopt.cli.train_vqvae:register_models",
        ("driveopt.training.vqvae:train_vqvae", "driveopt.training.pixelcnn:train_pixelcnn"),
        "driveopt.learned.pixelcnn:load_vqvae_prior",
        shipped="driveopt.priors.vqvae:shipped_weights", prior="driveopt.priors.vqvae:load_prior",
        prior_factory="driveopt.priors.vqvae:vqvae_prior", weights_option="--vqvae-weights",
        checkpoint="PixelCNN checkpoint, which embeds its VQ-VAE"),
    LearnedKind(
        "filter", "learned safety filter", ("filter",), "driveopt.cli.train_filter:register_models",
        ("driveopt.training.filter:train_filter",), "driveopt.learned.filter:load_filter",
        shipped="driveopt.safety.learned:shipped_weights", filter_factory="driveopt.safety.learned:learned_filter"),
    LearnedKind(
        "cvae-multipliers", "CVAE with multipliers", ("cvae-multipliers",),
        "driveopt.cli.train_cvae_multipliers:register_models", ("driveopt.training.cvae_multipliers:train_cvae_multipliers",),
        "driveopt.learned.cvae_multipliers:load_model", shipped="driveopt.learned.cvae_multipliers:shipped_weights",
        prior="driveopt.priors.cvae_multipliers:load_prior",
        prior_factory="driveopt.priors.cvae_multipliers:cvae_multipliers_prior",
        filter_factory="driveopt.safety.cvae_multipliers:filter_for"),
    LearnedKind(
        "rl", "RL policy", ("dqn", "ppo"), "driveopt.cli.train_rl:register_models", ("driveopt.training.rl:train_agent",) * 2,
        "driveopt.rl.policy:load_model"),
)
"""Every learned kind, in the order `driveopt train` lists their subcommands."""


def kind(name: str) -> LearnedKind:
    """The row of ``name``; KindError naming the known kinds for any other name."""
    for row in KINDS:
        if row.name == name:
            return row
    raise KindError(f"unknown learned kind {name!r}; known: {', '.join(k.name for k in KINDS)}")


def offline_kinds() -> tuple[LearnedKind, ...]:
    """The kinds whose priors plot-prior draws and the prior metrics measure, in table order."""
    return tuple(k for k in KINDS if k.offline)


def train_models() -> tuple[str, ...]:
    """Every `driveopt train` subcommand, in table order."""
    return tuple(model for row in KINDS for model in row.train)


def resolve(ref: str) -> Any:
    """The attribute ``ref`` (``"package.module:attribute"``) names, its module imported now; KindError when the
    module has no such attribute."""
    module, _, attribute = ref.partition(":")
    try:
        return getattr(importlib.import_module(module), attribute)
    except AttributeError as exc:
        raise KindError(f"learned-kind entry {ref!r} names nothing: {exc}") from exc
