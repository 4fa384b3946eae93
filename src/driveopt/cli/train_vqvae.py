"""``driveopt train vqvae`` and ``driveopt train pixelcnn`` (P2's learned sampler), registered by :mod:`driveopt.cli.train`.

The settings are checked (:class:`~driveopt.training.vqvae.TrainConfig`, which both trainers take,
:class:`~driveopt.learned.vqvae.VQVAEConfig`, :class:`~driveopt.learned.pixelcnn.PixelCNNConfig`)
before any data is read or output written.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import add_split_arguments, positive_int


def _common(p: argparse.ArgumentParser, weights: str) -> None:
    p.add_argument("--data", nargs="+", required=True, help="demonstration HDF5 files with modes (schema version 2)")
    p.add_argument("--out", required=True, help=f"output folder (rerun to resume): last.ckpt, {weights}, history.json")
    p.add_argument("--epochs", type=positive_int, default=60, help="passes over the training data")
    p.add_argument("--batch-size", type=positive_int, default=256, help="modes per step")
    p.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate (x0.1 every 20 epochs)")
    add_split_arguments(p)


def register_models(models) -> None:
    """Add the ``vqvae`` and ``pixelcnn`` subcommands to ``driveopt train``'s model subparsers."""
    p = models.add_parser("vqvae", help="VQ-VAE over the expert's modes (P2 §III-A) from `driveopt collect` demonstrations")
    _common(p, "vqvae.ckpt")
    p.add_argument("--beta", type=float, default=0.2, help="commitment weight")
    p.add_argument("--codes", type=int, default=16, help="codebook size")
    p.add_argument("--latent-dim", type=positive_int, default=5, help="size of each of the 10 latent vectors")
    p.add_argument("--hidden", type=positive_int, nargs="+", default=[256, 256], help="decoder MLP widths")
    p.add_argument("--no-reseed", action="store_true", help="keep dead codes (default: re-seed them from encoder outputs)")
    p.set_defaults(func=run_vqvae)
    p = models.add_parser("pixelcnn", help="conditional PixelCNN over a trained VQ-VAE's codes (P2 §III-B): the planner's weights")
    _common(p, "pixelcnn.ckpt")
    p.add_argument("--vqvae", required=True, help="the VQ-VAE checkpoint (vqvae.ckpt of `driveopt train vqvae`)")
    p.add_argument("--channels", type=positive_int, default=64, help="feature channels of each PixelCNN layer")
    p.add_argument("--layers", type=int, default=5, help="mask-B layers after the mask-A one")
    p.add_argument("--kernel", type=positive_int, default=7, help="odd convolution width")
    p.set_defaults(func=run_pixelcnn)


def _train_config(args: argparse.Namespace, **extra):
    from driveopt.training.vqvae import TrainConfig

    return TrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, validation_fraction=args.validation,
                       train_episodes=args.train_episodes, seed=args.seed, **extra)


def _report(summary: dict, unit: str) -> None:
    last = summary["history"][-1] if summary["history"] else {}
    rows = summary["rows"]
    print(f"trained {summary['epochs']} epochs on {rows['train_modes']} modes of {rows['train']} rows "
          f"({rows['validation_modes']} of {rows['validation']} validation) in {summary['seconds']:.0f} s; last train loss "
          f"{last.get('train_loss', float('nan')):.3f}, best validation loss {summary['best_val_loss']:.3f} {unit}; "
          f"weights: {summary['weights'] or 'none written yet'}")


def run_vqvae(args: argparse.Namespace) -> int:
    from driveopt.learned.vqvae import VQVAEConfig
    from driveopt.training.vqvae import train_vqvae

    cfg = VQVAEConfig(beta=args.beta, codebook_size=args.codes, latent_dim=args.latent_dim, decoder_hidden=tuple(args.hidden))
    tcfg = _train_config(args, reseed_dead_codes=not args.no_reseed)
    summary = train_vqvae(args.data, args.out, cfg, tcfg, validation_paths=args.validation_data)
    _report(summary, "")
    last = summary["history"][-1] if summary["history"] else {}
    if last:
        print(f"codebook: perplexity {last['train_perplexity']:.2f} of {cfg.codebook_size} codes, "
              f"{last['train_dead_codes']} dead in the last epoch")
    return 0


def run_pixelcnn(args: argparse.Namespace) -> int:
    from driveopt.learned.pixelcnn import PixelCNNConfig
    from driveopt.learned.vqvae import load_vqvae
    from driveopt.training.pixelcnn import train_pixelcnn

    tcfg = _train_config(args)
    vq_cfg = load_vqvae(args.vqvae)[0]
    cfg = PixelCNNConfig.for_vqvae(vq_cfg, channels=args.channels, layers=args.layers, kernel_size=args.kernel)
    summary = train_pixelcnn(args.data, args.vqvae, args.out, cfg, tcfg, validation_paths=args.validation_data)
    _report(summary, "nats/code")
    return 0
