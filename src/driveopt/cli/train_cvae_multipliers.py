"""``driveopt train cvae-multipliers`` ([5]'s CVAE: set-points and initial multipliers), registered by
:mod:`driveopt.cli.train`.

The settings are checked (:class:`~driveopt.training.cvae_multipliers.TrainConfig`,
:class:`~driveopt.learned.cvae_multipliers.MultiplierCVAEConfig`) and the planner looked up before any data is read
or output written.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import add_split_arguments, positive_int


def register_models(models) -> None:
    """Add the ``cvae-multipliers`` subcommand to ``driveopt train``'s model subparsers."""
    p = models.add_parser("cvae-multipliers", help="P2's CVAE baseline [5]: set-points and initial multipliers, trained "
                                                   "through the set-point QP and the unrolled projection")
    p.add_argument("--data", nargs="+", required=True, help="demonstration HDF5 files")
    p.add_argument("--out", required=True, help="output folder (rerun to resume): last.ckpt, cvae-multipliers.ckpt, history.json")
    p.add_argument("--planner", default="cvae-multipliers", help="optimiser whose QP and projection it trains through")
    p.add_argument("--epochs", type=positive_int, default=60, help="passes over the training data")
    p.add_argument("--batch-size", type=positive_int, default=256, help="rows per step ([5]: 8000)")
    p.add_argument("--lr", type=float, default=2e-4, help="AdamW learning rate (x0.1 every 30 epochs; [5]: 2e-4)")
    p.add_argument("--beta", type=float, default=3.5, help="KL weight after annealing ([5]: 3.5)")
    p.add_argument("--anneal-epochs", type=int, default=4000, help="epochs over which beta rises from 0 ([5]: 4000)")
    p.add_argument("--unroll", type=positive_int, default=20, help="projection iterations unrolled ([5]: 20)")
    p.add_argument("--residual-weight", type=float, default=1.0, help="weight of the projected residual [m^2 per unit]")
    p.add_argument("--velocity-weight", type=float, default=5e-4, help="weight of the speed error's L2 norm [m^2 per m/s]")
    p.add_argument("--latent", type=positive_int, default=2, help="latent dimension")
    p.add_argument("--hidden", type=positive_int, nargs="+", default=[256, 256, 256], help="encoder and decoder MLP widths")
    p.add_argument("--multiplier-hidden", type=positive_int, nargs="+", default=[256, 256], help="multiplier head MLP widths")
    add_split_arguments(p)
    p.set_defaults(func=run_cvae_multipliers)


def run_cvae_multipliers(args: argparse.Namespace) -> int:
    from driveopt.learned.cvae import CVAEConfig
    from driveopt.learned.cvae_multipliers import MultiplierCVAEConfig
    from driveopt.registry import get_optimiser
    from driveopt.training.cvae_multipliers import TrainConfig, train_cvae_multipliers

    spec = get_optimiser(args.planner)
    inner = CVAEConfig(latent_dim=args.latent, hidden=tuple(args.hidden), v_max=spec.config.projection.v_max,
                       basis=spec.config.basis, qp=spec.config.qp)
    cfg = MultiplierCVAEConfig(cvae=inner, multiplier_hidden=tuple(args.multiplier_hidden))
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, beta=args.beta,
                       anneal_epochs=args.anneal_epochs, unroll=args.unroll, residual_weight=args.residual_weight,
                       velocity_weight=args.velocity_weight, validation_fraction=args.validation,
                       train_episodes=args.train_episodes, seed=args.seed)
    summary = train_cvae_multipliers(args.data, args.out, cfg, tcfg, config=spec.config, validation_paths=args.validation_data)
    last = summary["history"][-1] if summary["history"] else {}
    residual = last.get("val_residual", last.get("train_residual", float("nan")))
    print(f"trained {summary['epochs']} epochs on {summary['rows']['train']} rows ({summary['rows']['validation']} validation) "
          f"in {summary['seconds']:.0f} s; last train loss {last.get('train_loss', float('nan')):.3f}, residual after "
          f"projection {residual:.3f}; weights: {summary['weights'] or 'none written yet'}")
    return 0
