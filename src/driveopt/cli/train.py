"""``driveopt train MODEL``: fit a learned component to demonstrations (or, for the RL baselines, in the simulator),
resumable.

The models are the ``train`` subcommands of every row of :data:`driveopt.learned_kinds.KINDS`, each registered by
its row's ``train_cli`` (:mod:`driveopt.cli.train_cvae`, :mod:`driveopt.cli.train_vqvae`, ...). Their settings are
checked before any data is read or output written.
"""

from __future__ import annotations

from driveopt import learned_kinds


def register(sub) -> None:
    p = sub.add_parser("train", help=f"train a learned component ({', '.join(learned_kinds.train_models())}); resumable")
    models = p.add_subparsers(dest="model", required=True)
    for kind in learned_kinds.KINDS:
        learned_kinds.resolve(kind.train_cli)(models)
