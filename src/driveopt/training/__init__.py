"""Training: the loops that fit the learned components through the planner and the simulator.

``harness`` (what every trainer shares: settings, the held-out split, batching, the optimiser, the resumable epoch
loop with the best checkpoint), then one module per trained thing: ``cvae`` (``driveopt train cvae``), ``vqvae``
(``driveopt train vqvae``), ``pixelcnn`` (``driveopt train pixelcnn``, over a trained VQ-VAE's codes), ``filter``
(``driveopt train filter``) and ``rl`` (``driveopt train dqn|ppo``: Stable-Baselines3 runs its own loop and writes its
own checkpoints, so it does not use the harness). The networks themselves are in :mod:`driveopt.learned`.
"""
