"""``driveopt train dqn|ppo``: P1's RL baselines (§V-A4, Table II) with Stable-Baselines3, resumable.

Registered under ``driveopt train`` by :func:`register_models`. Stable-Baselines3 and PyTorch are
imported only when one of these commands runs (without them: one line naming
``pip install 'driveopt[rl]'``). Options are checked before anything is written.
"""

from __future__ import annotations

import argparse

from driveopt.cli.common import positive_int, seed


def register_models(models) -> None:
    for algo, what in (("dqn", "Deep Q-Network"), ("ppo", "Proximal Policy Optimization")):
        p = models.add_parser(algo, help=f"P1's {what} baseline (five behaviours every 1 s); Stable-Baselines3, resumable")
        p.add_argument("--scenario", required=True, help="scenario name (see `driveopt scenarios`), e.g. two-lane-d1.0")
        p.add_argument("--scenario-config", help="JSON file overriding scenario fields (e.g. {\"vehicles_count\": 20})")
        p.add_argument("--steps", type=positive_int, required=True, help="env steps (1 s each) in all (P1: 5000000)")
        p.add_argument("--out", required=True, help="output folder (rerun to resume): last.zip, best.zip, curve.csv, summary.json, tensorboard/")
        p.add_argument("--envs", type=positive_int, default=1, help="parallel envs (worker processes when > 1)")
        p.add_argument("--eval-every", type=positive_int, default=10_000, help="env steps between evaluations and checkpoints")
        p.add_argument("--eval-episodes", type=positive_int, default=5, help="fixed-seed episodes per evaluation")
        p.add_argument("--seed", type=seed, default=0, help="training seed (env i starts from seed + i)")
        p.add_argument("--device", default="cpu", help="PyTorch device (cpu, cuda, auto; a GPU needs a CUDA torch build)")
        p.set_defaults(func=run_rl, algo=algo)


def run_rl(args: argparse.Namespace) -> int:
    from driveopt.sim.scenarios import resolve_scenario
    from driveopt.training.rl import train_agent

    scenario = resolve_scenario(args.scenario, config_file=args.scenario_config)
    summary = train_agent(args.algo, scenario, args.steps, args.out, envs=args.envs, eval_every=args.eval_every,
                          eval_episodes=args.eval_episodes, seed=args.seed, device=args.device)
    last, best = summary["last_eval"] or {}, summary["best"] or {}
    print(f"trained {args.algo} to {summary['steps']} steps ({summary['steps_this_run']} this run) in {summary['seconds']:.0f} s: "
          f"{summary['train_steps_per_s'] or 0:.1f} training steps/s with {summary['envs']} env(s); "
          f"last evaluation: collision rate {last.get('collision_rate', float('nan')):.2f}, "
          f"mean return {last.get('mean_return', float('nan')):.2f}; best at step {best.get('step', '-')}: {summary['policy']}")
    if summary.get("tensorboard"):
        print(f"  TensorBoard: tensorboard --logdir {summary['tensorboard']}")
    return 0
