"""The table of learned kinds: every row's code exists, and the commands that treat the kinds alike (``driveopt train``,
``driveopt plot-prior``, the prior metrics) list exactly the table's rows, a new row included."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import types
from pathlib import Path

import jax
import numpy as np
import pytest

from driveopt import learned_kinds
from driveopt.cli import build_parser
from driveopt.config import PlannerConfig
from driveopt.experiments import prior_metrics
from driveopt.learned_kinds import KINDS, KindError, LearnedKind, kind, offline_kinds, resolve, train_models
from driveopt.pytree import pytree_dataclass, static
from driveopt.sampler import GaussianPrior

FAKE_MODULE = "fake_learned_kind"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {option for action in parser._actions for option in action.option_strings}


@pytest.fixture
def fake_kind(monkeypatch, tmp_path):
    """A learned prior that is only a table row and a module: one train subcommand, a weights option, a loader that
    returns a Gaussian prior, weights shipped for two-lane roads only."""
    shipped = tmp_path / "fake-two-lane.ckpt"
    shipped.write_bytes(b"fake weights")
    module = types.ModuleType(FAKE_MODULE)

    def register_models(models):
        models.add_parser("fake", help="a fake learned prior").set_defaults(func=lambda args: 0)

    module.register_models = register_models
    module.shipped_weights = lambda lanes: shipped if lanes == 2 else None
    module.load_prior = lambda path, v_max, *, lanes=None: GaussianPrior.from_config(PlannerConfig().sampler, v_max)
    monkeypatch.setitem(sys.modules, FAKE_MODULE, module)
    row = LearnedKind("fake", "Fake", ("fake",), f"{FAKE_MODULE}:register_models", (f"{FAKE_MODULE}:register_models",),
                      f"{FAKE_MODULE}:load_prior", shipped=f"{FAKE_MODULE}:shipped_weights", prior=f"{FAKE_MODULE}:load_prior",
                      weights_option="--fake-weights", checkpoint="fake checkpoint")
    monkeypatch.setattr(learned_kinds, "KINDS", (*KINDS, row))
    return row


def test_every_row_names_code_that_exists():
    assert len({k.name for k in KINDS}) == len(KINDS) and len(set(train_models())) == len(train_models())
    for row in KINDS:
        assert len(row.trainers) == len(row.train) >= 1, row.name
        refs = [row.train_cli, *row.trainers, row.loader, row.shipped, row.prior, row.prior_factory, row.filter_factory]
        for ref in filter(None, refs):
            assert callable(resolve(ref)), ref
        assert kind(row.name) is row
    assert [k.name for k in offline_kinds()] == ["cvae", "vqvae"]
    assert train_models() == ("cvae", "vqvae", "pixelcnn", "filter", "cvae-multipliers", "dqn", "ppo")
    with pytest.raises(KindError, match="known: cvae, vqvae"):
        kind("gan")
    with pytest.raises(KindError, match="names nothing"):
        resolve("driveopt.priors.cvae:no_such_function")


def test_the_shipped_weights_and_loaders_of_the_rows_are_the_modules_own():
    from driveopt.learned import cvae_multipliers
    from driveopt.priors import cvae, vqvae
    from driveopt.safety import learned

    for name, module in (("cvae", cvae), ("vqvae", vqvae), ("filter", learned), ("cvae-multipliers", cvae_multipliers)):
        for lanes in (2, 3, 4):
            assert kind(name).shipped_weights(lanes) == module.shipped_weights(lanes), (name, lanes)
    assert kind("cvae-multipliers").shipped_weights(4) is not None and kind("cvae-multipliers").shipped_weights(2) is None
    assert kind("rl").shipped_weights(4) is None  # the policies ship per algorithm: not this row's signature


def test_train_lists_exactly_the_tables_subcommands_a_new_row_included(fake_kind, capsys):
    parser = build_parser()
    train = _subparsers(parser)["train"]
    assert list(_subparsers(train)) == [*train_models()] and train_models()[-1] == "fake"
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert next(c.help for c in commands._choices_actions if c.dest == "train") == (
        f"train a learned component ({', '.join(train_models())}); resumable")
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "--help"])
    assert "fake                a fake learned prior" in capsys.readouterr().out


def test_plot_prior_and_the_prior_metrics_take_a_weights_option_per_offline_kind(fake_kind):
    plot = _subparsers(build_parser())["plot-prior"]
    weights = {o for o in _options(plot) if o.endswith("weights")}
    assert weights == {"--cvae-weights", "--weights", "--vqvae-weights", "--fake-weights"}
    args = plot.parse_args(["--fake-weights", "f.ckpt", "--weights", "c.ckpt"])
    assert (args.fake_weights, args.weights, args.vqvae_weights) == ("f.ckpt", "c.ckpt", None)
    assert prior_metrics.prior_names() == ("gaussian-p1", "gaussian", "cvae", "vqvae", "fake")


def test_the_prior_metrics_load_a_new_kind_from_its_row(fake_kind, capsys):
    config = PlannerConfig()
    priors, digests = prior_metrics.make_priors(["gaussian", "fake"], config, 2, {"fake": None})
    assert list(priors) == ["gaussian", "fake"] and isinstance(priors["fake"], GaussianPrior)
    assert list(digests) == ["fake"]
    priors, digests = prior_metrics.make_priors(["fake"], config, 4, {})  # nothing shipped for four lanes
    assert priors == {} and digests == {}
    assert "no fake weights shipped for 4-lane roads (pass --fake-weights): left out" in capsys.readouterr().err


def test_plot_prior_leaves_out_a_kind_without_weights_with_a_notice(fake_kind, monkeypatch, tmp_path, capsys):
    """Every offline kind gets a column: without weights for the road, a notice instead (checked before any plot)."""
    from driveopt.cli import plot_prior

    monkeypatch.setattr(learned_kinds, "KINDS", (fake_kind,))
    drawn = {}

    def plot_priors(priors, scene, config, out, **kw):
        drawn.update(priors=list(priors), notes=kw["notes"])
        return types.SimpleNamespace(path=out, columns=list(priors))

    monkeypatch.setattr("driveopt.viz.prior_plot.plot_priors", plot_priors)
    args = _subparsers(build_parser())["plot-prior"].parse_args(["--out", str(tmp_path / "p.png")])
    assert plot_prior.run(args) == 0
    assert drawn["notes"] == ["Fake: no weights shipped for 4-lane roads (pass --fake-weights FILE): column left out"]
    assert len(drawn["priors"]) == 2  # the two Gaussians
    args = _subparsers(build_parser())["plot-prior"].parse_args(["--out", str(tmp_path / "p.png"),
                                                                "--fake-weights", str(Path(__file__))])
    assert plot_prior.run(args) == 0
    assert drawn["priors"][-1] == f"Fake ({Path(__file__).name})" and drawn["notes"] == []


# ------------------------------------------------------------------------------------------ pytree dataclasses


@pytree_dataclass
class _Weights:
    params: dict
    normaliser: tuple
    config: tuple = static()
    scale: float = static(1.0)


def test_a_pytree_dataclass_has_its_weights_as_leaves_and_its_configuration_static():
    a = _Weights({"w": np.ones(2)}, (np.zeros(1),), ("mlp", 2))
    leaves, tree = jax.tree_util.tree_flatten(a)
    assert len(leaves) == 2 and tree == jax.tree_util.tree_structure(_Weights({"w": 0}, (0,), ("mlp", 2)))
    assert tree != jax.tree_util.tree_structure(_Weights({"w": 0}, (0,), ("mlp", 3)))  # another configuration
    assert jax.tree_util.tree_unflatten(tree, leaves).config == ("mlp", 2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.scale = 2.0
    with pytest.raises(TypeError):
        _Weights({}, ())  # the configuration is required


def test_the_learned_priors_and_filters_keep_weights_as_leaves_and_configuration_static():
    from driveopt.priors.cvae import CVAEPrior
    from driveopt.priors.cvae_multipliers import MultiplierCVAEPrior
    from driveopt.priors.vqvae import VQVAEPrior
    from driveopt.safety.cvae_multipliers import CVAEMultipliers
    from driveopt.safety.learned import LearnedFilter

    expected = {CVAEPrior: ({"params", "normaliser", "gaussian"}, {"config", "v_max", "gaussian_fraction"}),
                MultiplierCVAEPrior: ({"params", "normaliser"}, {"config", "v_max"}),
                VQVAEPrior: ({"vqvae_params", "normaliser", "pixelcnn_params"}, {"vqvae_config", "pixelcnn_config", "v_max"}),
                CVAEMultipliers: ({"params", "normaliser"}, {"config", "gamma_obs", "gamma_lane"}),
                LearnedFilter: ({"params", "normaliser"}, {"config"})}
    for cls, (leaves, static_fields) in expected.items():
        fields = dataclasses.fields(cls)
        assert {f.name for f in fields if not f.metadata.get("static")} == leaves, cls
        assert {f.name for f in fields if f.metadata.get("static")} == static_fields, cls
        assert cls.__dataclass_params__.frozen, cls
