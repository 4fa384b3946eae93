"""Drivers: who acts in the closed loop. ``base`` (the Driver protocol, Decision, DriverSpec),
``optimiser`` (any planner run by ``plan()``: config adaptation, prior, key, warm start, fallback
braking, P1's open-loop periods), ``idm`` (highway-env's IDM/MOBIL) and ``rl`` (P1's DQN/PPO baselines: a
Stable-Baselines3 policy choosing a behaviour every second). A new agent is one module
here plus one line in :mod:`driveopt.registry`."""
