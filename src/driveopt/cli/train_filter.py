"""``driveopt train filter`` (P2's learned safety filter), registered by :mod:`driveopt.cli.train`.

The settings are checked (:class:`~driveopt.training.filter.TrainConfig`,
:class:`~driveopt.learned.filter.FilterConfig`) and the planner looked up before any data is read or
output written.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import add_split_arguments, positive_int


def register_models(models) -> None:
    """Add the ``filter`` subcommand to ``driveopt train``'s model subparsers."""
    p = models.add_parser("filter", help="learned safety filter (P2 §III-C) through the unrolled projection, from demonstrations")
    p.add_argument("--data", nargs="+", required=True, help="demonstration HDF5 files (their observations)")
    p.add_argument("--out", required=True, help="output folder (rerun to resume): last.ckpt, filter.ckpt, history.json")
    p.add_argument("--samples-from", choices=["vqvae", "cvae", "gaussian"], default="vqvae",
                   help="prior the trajectories are drawn from (default vqvae, as P2)")
    p.add_argument("--prior-weights", help="its checkpoint: pixelcnn.ckpt or cvae.ckpt (default: the weights shipped for the road)")
    p.add_argument("--planner", default="vqvae-filter", help="optimiser whose projection the filter sets up (default vqvae-filter)")
    p.add_argument("--epochs", type=positive_int, default=30, help="passes over the training data")
    p.add_argument("--batch-size", type=positive_int, default=16, help="observations per step")
    p.add_argument("--samples", type=positive_int, default=64, help="trajectories per observation")
    p.add_argument("--unroll", type=positive_int, default=25,
                   help="projection iterations unrolled (the authors: 5; 25: the planner's iterations the filter is meant for)")
    p.add_argument("--residual-weight", type=float, default=1000.0, help="s of P2 eq. 9 [m^2 per unit of residual]")
    p.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate (x0.1 every 20 epochs)")
    p.add_argument("--hidden", type=positive_int, nargs="+", default=[256, 256, 256, 256], help="MLP widths")
    p.add_argument("--gamma-min", type=float, default=0.5,
                   help="lowest gamma the filter may predict, in (0, 1) (small gammas converge slowly)")
    add_split_arguments(p)
    p.add_argument("--save-every", type=positive_int, default=300,
                   help="seconds between the saves of last.ckpt inside an epoch (what an interruption can lose)")
    p.set_defaults(func=run_filter)


def run_filter(args: argparse.Namespace) -> int:
    from driveopt.learned.filter import FilterConfig
    from driveopt.registry import get_optimiser
    from driveopt.training.filter import TrainConfig, train_filter

    spec = get_optimiser(args.planner)
    cfg = FilterConfig(hidden=tuple(args.hidden), gamma_min=args.gamma_min, basis=spec.config.basis)
    tcfg = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, samples=args.samples, unroll=args.unroll,
                       residual_weight=args.residual_weight, samples_from=args.samples_from, learning_rate=args.lr,
                       validation_fraction=args.validation, train_episodes=args.train_episodes, seed=args.seed)
    summary = train_filter(args.data, args.out, cfg, tcfg, config=spec.config, prior_weights=args.prior_weights,
                           validation_paths=args.validation_data, save_every=args.save_every)
    last, kept, baseline = (summary["history"] or [{}])[-1], summary["kept"], summary["baseline"]
    if kept and "val_feasible" in kept:
        plain = f" (plain filter {baseline['feasible']:.1%}, {baseline['loss']:.2f})"
        chosen = (f"kept epoch {kept['epoch']}: {kept['val_feasible']:.1%} of validation samples feasible, "
                  f"loss {kept['val_loss']:.2f}{plain}")
    elif kept:
        chosen = f"kept epoch {kept['epoch']}: {kept['train_feasible']:.1%} of training samples feasible"
    else:
        chosen = "no epoch finished yet"
    print(f"trained {summary['epochs']} epochs on {summary['rows']['train']} observations ({summary['rows']['validation']} "
          f"validation) in {summary['seconds']:.0f} s; last train loss {last.get('train_loss', float('nan')):.2f}; "
          f"{chosen}; weights: {summary['weights'] or 'none written yet'}")
    return 0
