"""The planners ``driveopt planners`` prints, without importing them: the registry behind them
(:mod:`driveopt.registry`) loads JAX and Flax first (seconds), the listing answers in a fraction of a second.

A copy of the registry's names and descriptions, kept equal to it by ``tests/cli/test_catalogue.py``, which fails
naming the rows to paste here when a planner is added, removed or changed. (Scenarios are listed from their registry,
:mod:`driveopt.sim.scenarios`, which loads nothing heavy.)
"""

from __future__ import annotations

PLANNERS: tuple[tuple[str, str], ...] = (
    ("bilevel", "P1 bi-level optimiser: Gaussian start, 150 samples x 5 CEM iterations x 20 projection iterations (real time on 2 CPU cores; P1: 1000 samples)"),
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
     ("P1's CVAE through P2's pipeline: 1000 CVAE samples through vqvae's one pass (barrier projection, 100 iterations), "
      "least-cost feasible; differs from vqvae only in the prior (shipped weights; Gaussian if none)")),
    ("cvae-multipliers",
     ("P2's CVAE baseline as its reference [5] built it: 1000 CVAE samples of set-points, each projected (75 "
      "iterations) from the initial multipliers the model predicts for it, one pass (shipped four-lane weights, or "
      "--weights from `driveopt train cvae-multipliers`; Gaussian and zero multipliers if none)")),
    ("random", "one Gaussian draw of set-points, no adaptation (MPC-Random)"),
    ("grid", "fixed grid: constant speed x target lane x change quarter (MPC-Grid)"),
    ("vanilla", "single speed set-point v_des (reached by at most 5 m/s per quarter of the horizon) in the current lane, "
                "no behavioural layer (MPC-Vanilla)"),
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
    ("bilevel-faithful",
     ("P1 Alg. 1 as P1's authors ran it: 1000 samples from N(m, diag(30, 46)), m the previous call's final "
      "mean (before the first call the current motion), 5 CEM iterations x 20 projection iterations, "
      "elites 150 -> 50; P1's ranking and its authors' cost, no driveopt safety machinery, a plan every "
      "0.1 s")),
    ("cvae-faithful",
     ("P1's MPC-Bi-Level as its authors' main_bilevel.py ran it: bilevel-faithful with the learned CVAE's "
      "samples as its first batch (shipped weights; Gaussian if none); P1's ranking and its authors' cost, "
      "no driveopt safety machinery, a plan every 0.1 s")),
    ("random-faithful",
     ("MPC-Random as P1's authors ran it: 1000 samples from N((v_des, y0), diag(16, 46)), one pass of 100 "
      "projection iterations, elites 150; P1's ranking and its authors' cost, no driveopt safety "
      "machinery, a plan every 0.1 s")),
    ("grid-faithful",
     ("MPC-Grid as P1's authors ran it: 50 speeds on v_des +- 16 m/s x 20 offsets across the road, held "
      "over the horizon, one pass of 100 projection iterations, elites 150; P1's ranking and its authors' "
      "cost, no driveopt safety machinery, a plan every 0.1 s")),
    ("vanilla-faithful",
     ("MPC-Vanilla as P1's authors ran it: speed set-point v_des, 1000 lateral guesses (the least "
      "obstructed of 30000 smooth paths), one pass of 100 projection iterations, elites 300; P1's ranking "
      "and its authors' cost, no driveopt safety machinery, a plan every 0.1 s")),
    ("batch-faithful",
     ("Batch-MPC as P1's authors' MPC-Grid: goals (x_0 + v T, y_f) on grid-faithful's 50 x 20 grid with "
      "terminal constraints, one pass of 100 projection iterations, elites 150; P1's ranking and its "
      "authors' cost, no driveopt safety machinery, a plan every 0.1 s")),
    ("vqvae-faithful",
     ("vqvae as P2's authors ran it (inferenceJax3.py): the same samples, prior and filter, the least cost "
      "+ residual of the 150 lowest residuals executed whatever its residual, no driveopt safety machinery,"
      " a plan every 0.1 s")),
    ("vqvae-filter-faithful",
     ("vqvae-filter as P2's authors ran it (inferenceJax3.py): the same samples, prior and filter, the "
      "least cost + residual of the 150 lowest residuals executed whatever its residual, no driveopt safety"
      " machinery, a plan every 0.1 s")),
    ("cvae-filter-faithful",
     ("cvae-filter as P2's authors ran it (inferenceJax3.py): the same samples, prior and filter, the least"
      " cost + residual of the 150 lowest residuals executed whatever its residual, no driveopt safety "
      "machinery, a plan every 0.1 s")),
    ("cvae-multipliers-faithful",
     ("cvae-multipliers as [5]'s authors ran it (main_diffproj.py): the same samples and multipliers, the least "
      "residual + 1e-3 speed error of the 10 lowest residuals executed whatever its residual, no driveopt safety "
      "machinery, a plan every 0.1 s")),
    ("idm", "highway-env's IDM/MOBIL driver on the ego (rule-based reference)"),
    ("dqn",
     ("P1's DQN baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
      "(shipped policy for the road's lane count, or --weights)")),
    ("ppo",
     ("P1's PPO baseline: one of five behaviours every 1 s, tracked by upstream's set-point controller "
      "(shipped policy for the road's lane count, or --weights)")),
)
