"""P1's reinforcement-learning baselines (§V-A4, App. III): DQN and PPO over five driving behaviours.

- :mod:`driveopt.rl.env`: the gymnasium training env over driveopt's scenarios (the planner's 55-dim
  observation, five behaviours tracked by upstream's set-point controller, a reward of named terms)
  and the behaviour controller the closed-loop driver shares with it;
- :mod:`driveopt.rl.policy`: policy files (Stable-Baselines3 zips with a driveopt record), loading,
  checks, the shipped policies, and the one-line error when the ``rl`` extra is missing.

Training them (``driveopt train dqn|ppo``) is :mod:`driveopt.training.rl`.

Stable-Baselines3 and PyTorch (``pip install 'driveopt[rl]'``) are imported only inside the code paths
that train or run a policy, so ``import driveopt`` and every other command work without them. The
driver that runs a policy in the standard closed loop is :mod:`driveopt.drivers.rl`.
"""
