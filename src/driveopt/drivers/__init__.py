"""Drivers: who acts in the closed loop. ``base`` (the Driver protocol, Decision, DriverSpec),
``optimiser`` (any planner run by ``plan()``: config adaptation, prior, key, warm start, fallback
braking, P1's open-loop periods) and ``idm`` (highway-env's IDM/MOBIL). A new agent is one module
here plus one line in :mod:`driveopt.registry`."""
