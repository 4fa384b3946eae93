"""``driveopt train cvae`` (P1's learned warm start), registered by :mod:`driveopt.cli.train`.

The settings are checked (:class:`~driveopt.training.cvae.TrainConfig`,
:class:`~driveopt.learned.cvae.CVAEConfig`: NaN, infinite and out-of-range values are refused) before
any data is read or output written.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import add_split_arguments, positive_int


def register_models(models) -> None:
    """Add the ``cvae`` subcommand to ``driveopt train``'s model subparsers."""
    p = models.add_parser("cvae", help="CVAE warm start (P1 §III-D) from demonstrations of `driveopt collect`")
    p.add_argument("--data", nargs="+", required=True, help="demonstration HDF5 files")
    p.add_argument("--out", required=True, help="output folder (rerun to resume): last.ckpt, cvae.ckpt, history.json")
    p.add_argument("--epochs", type=positive_int, default=60, help="passes over the training data")
    p.add_argument("--batch-size", type=positive_int, default=256, help="rows per step")
    p.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate (x0.1 every 20 epochs)")
    p.add_argument("--beta", type=float, default=1.0, help="KL weight after annealing")
    p.add_argument("--latent", type=positive_int, default=2, help="latent dimension")
    p.add_argument("--hidden", type=positive_int, nargs="+", default=[256, 256, 256], help="MLP widths")
    add_split_arguments(p)
    p.set_defaults(func=run_cvae)


def run_cvae(args: argparse.Namespace) -> int:
    from driveopt.learned.cvae import CVAEConfig
    from driveopt.training.cvae import TrainConfig, train_cvae

    cfg = CVAEConfig(latent_dim=args.latent, hidden=tuple(args.hidden))
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, beta=args.beta,
                       validation_fraction=args.validation, train_episodes=args.train_episodes, seed=args.seed)
    summary = train_cvae(args.data, args.out, cfg, tcfg, validation_paths=args.validation_data)
    last = summary["history"][-1] if summary["history"] else {}
    print(f"trained {summary['epochs']} epochs on {summary['rows']['train']} rows ({summary['rows']['validation']} validation) "
          f"in {summary['seconds']:.0f} s; last train loss {last.get('train_loss', float('nan')):.3f}, "
          f"best validation loss {summary['best_val_loss']:.3f}; weights: {summary['weights'] or 'none written yet'}")
    return 0
