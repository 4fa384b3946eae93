"""Training: the loops that fit the learned components through the planner and the simulator.

``harness`` (what every trainer shares: settings, the held-out split, the resumable epoch loop, the optimiser, the
best checkpoint), then one module per trained thing: ``cvae`` (``driveopt train cvae``), ``vqvae`` (``driveopt train
vqvae`` and ``driveopt train pixelcnn``), ``filter`` (``driveopt train filter``) and ``rl`` (``driveopt train
dqn|ppo``). The networks themselves are in :mod:`driveopt.learned`.
"""
