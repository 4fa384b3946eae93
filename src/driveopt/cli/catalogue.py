"""The planners ``driveopt planners`` prints, without importing them: the registry behind them
(:mod:`driveopt.registry`) loads JAX and Flax first (seconds), the listing answers in a fraction of a second.

A copy of the registry's names and descriptions, kept equal to it by ``tests/cli/test_catalogue.py``, which fails
naming the rows to paste here when a planner is added, removed or changed. (Scenarios are listed from their registry,
:mod:`driveopt.sim.scenarios`, which loads nothing heavy.)
"""

from __future__ import annotations

PLANNERS: tuple[tuple[str, str], ...] = (
    ("bilevel", "P1 bi-level optimiser: Gaussian start, 5 CEM iterations x 20 projection iterations"),
    ("bilevel-p1", "P1's Gaussian start exactly: independent set-points, no warm start (Fig. 9's baseline)"),
    ("cvae", "P1 bi-level optimiser started from the learned CVAE only (shipped weights; Gaussian if none)"),
    ("cvae-mix", "bi-level optimiser: half the first batch from the CVAE, half from the bilevel Gaussian (warm start)"),
    ("vqvae",
     ("P2: 1000 PixelCNN/VQ-VAE samples, one pass of the barrier projection (100 iterations), least-cost "
      "feasible (shipped weights; Gaussian if none)")),
    ("vqvae-filter",
     ("P2's full pipeline: vqvae with the learned safety filter setting up the barrier projection (shipped "
      "weights; without filter weights the plain filter, without VQ-VAE weights the Gaussian)")),
    ("vqvae-cem", "P1 bi-level optimiser started from PixelCNN/VQ-VAE samples (shipped weights; Gaussian if none)"),
    ("cvae-filter",
     ("P2's baseline: 1000 CVAE samples through vqvae's one pass (barrier projection, 100 iterations), "
      "least-cost feasible; differs from vqvae only in the prior (shipped weights; Gaussian if none)")),
    ("random", "one Gaussian draw of set-points, no adaptation (MPC-Random)"),
    ("grid", "fixed grid: constant speed x target lane x change quarter (MPC-Grid)"),
    ("vanilla", "single speed set-point v_des in the current lane, no behavioural layer (MPC-Vanilla)"),
    ("batch", "goal positions (x_f, y_f) on a grid with terminal constraints (Batch-MPC)"),
    ("random-p1",
     ("P1-faithful MPC-Random: random without feasibility-first ranking, stop rows, structured first batch, "
      "free lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback (nor "
      "its straightening or sideways stops), contact guard, braking prediction or approach-ranked "
      "neighbours; 5 periods per plan")),
    ("grid-p1",
     ("P1-faithful MPC-Grid: grid without feasibility-first ranking, stop rows, structured first batch, "
      "free lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback (nor "
      "its straightening or sideways stops), contact guard, braking prediction or approach-ranked "
      "neighbours; 5 periods per plan")),
    ("vanilla-p1",
     ("P1-faithful MPC-Vanilla: vanilla without feasibility-first ranking, stop rows, structured first "
      "batch, free lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback "
      "(nor its straightening or sideways stops), contact guard, braking prediction or approach-ranked "
      "neighbours; 5 periods per plan")),
    ("batch-p1",
     ("P1-faithful Batch-MPC: batch without feasibility-first ranking, stop rows, structured first batch, "
      "free lateral start, plan consistency, course bound, per-sample turned box, brake-now fallback (nor "
      "its straightening or sideways stops), contact guard, braking prediction or approach-ranked "
      "neighbours; 5 periods per plan")),
    ("idm", "highway-env's IDM/MOBIL driver on the ego (rule-based reference)"),
    ("dqn",
     ("P1's DQN baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
      "(shipped policy for the road's lane count, or --weights)")),
    ("ppo",
     ("P1's PPO baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
      "(shipped policy for the road's lane count, or --weights)")),
)
