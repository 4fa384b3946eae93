"""The names the listing commands print, without importing what they name: ``driveopt scenarios`` and ``driveopt
planners`` answer in a fraction of a second, where the registries behind them (:mod:`driveopt.sim.scenarios`,
:mod:`driveopt.registry`) load highway-env, JAX and Flax first (seconds).

A copy of the registries' listing fields, kept equal to them by ``tests/cli/test_catalogue.py``, which fails naming
the rows to paste here when a scenario or planner is added, removed or changed.
"""

from __future__ import annotations

from typing import NamedTuple


class ScenarioLine(NamedTuple):
    """What ``driveopt scenarios`` prints of one scenario (:class:`driveopt.sim.scenarios.Scenario`)."""

    name: str
    road: str  # highway, two-way or merge
    lanes: int  # [-]
    density: float  # [-] highway-env's vehicles_density
    speed_limit: float  # [m/s] the neighbours' limit
    target_speeds: tuple[float, float]  # [m/s] range of the neighbours' IDM target speeds
    duration: float  # [s] episode length


SCENARIOS: tuple[ScenarioLine, ...] = (
    ScenarioLine("two-lane-d1.0", "highway", 2, 1.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("two-lane-d1.5", "highway", 2, 1.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("two-lane-d2.0", "highway", 2, 2.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("two-lane-d2.5", "highway", 2, 2.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("two-lane-d3.0", "highway", 2, 3.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("four-lane-d1.0", "highway", 4, 1.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("four-lane-d1.5", "highway", 4, 1.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("four-lane-d2.0", "highway", 4, 2.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("four-lane-d2.5", "highway", 4, 2.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("four-lane-d3.0", "highway", 4, 3.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("two-lane-d1.0-slow", "highway", 2, 1.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("two-lane-d1.5-slow", "highway", 2, 1.5, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("two-lane-d2.0-slow", "highway", 2, 2.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("two-lane-d2.5-slow", "highway", 2, 2.5, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("two-lane-d3.0-slow", "highway", 2, 3.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("four-lane-d1.0-slow", "highway", 4, 1.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("four-lane-d1.5-slow", "highway", 4, 1.5, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("four-lane-d2.0-slow", "highway", 4, 2.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("four-lane-d2.5-slow", "highway", 4, 2.5, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("four-lane-d3.0-slow", "highway", 4, 3.0, 7.0, (4.8999999999999995, 5.6000000000000005), 50.0),
    ScenarioLine("three-lane-d1.0", "highway", 3, 1.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("three-lane-d1.5", "highway", 3, 1.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("three-lane-d2.0", "highway", 3, 2.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("three-lane-d2.5", "highway", 3, 2.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("three-lane-d3.0", "highway", 3, 3.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("five-lane-d1.0", "highway", 5, 1.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("five-lane-d1.5", "highway", 5, 1.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("five-lane-d2.0", "highway", 5, 2.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("five-lane-d2.5", "highway", 5, 2.5, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("five-lane-d3.0", "highway", 5, 3.0, 15.0, (10.5, 12.0), 50.0),
    ScenarioLine("p2-four-lane-d1.0", "highway", 4, 1.0, 15.0, (0.0, 15.0), 50.0),
    ScenarioLine("p2-four-lane-d1.5", "highway", 4, 1.5, 15.0, (0.0, 15.0), 50.0),
    ScenarioLine("p2-four-lane-d2.0", "highway", 4, 2.0, 15.0, (0.0, 15.0), 50.0),
    ScenarioLine("p2-four-lane-d2.5", "highway", 4, 2.5, 15.0, (0.0, 15.0), 50.0),
    ScenarioLine("p2-four-lane-d3.0", "highway", 4, 3.0, 15.0, (0.0, 15.0), 50.0),
    ScenarioLine("p2-four-lane-d1.0-slow", "highway", 4, 1.0, 7.0, (0.0, 7.0), 50.0),
    ScenarioLine("p2-four-lane-d1.5-slow", "highway", 4, 1.5, 7.0, (0.0, 7.0), 50.0),
    ScenarioLine("p2-four-lane-d2.0-slow", "highway", 4, 2.0, 7.0, (0.0, 7.0), 50.0),
    ScenarioLine("p2-four-lane-d2.5-slow", "highway", 4, 2.5, 7.0, (0.0, 7.0), 50.0),
    ScenarioLine("p2-four-lane-d3.0-slow", "highway", 4, 3.0, 7.0, (0.0, 7.0), 50.0),
    ScenarioLine("two-way", "two-way", 2, 1.0, 15.0, (10.5, 12.0), 30.0),
    ScenarioLine("merge", "merge", 2, 1.0, 15.0, (10.5, 12.0), 30.0),
)
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
