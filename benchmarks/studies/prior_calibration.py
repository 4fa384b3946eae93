"""Are the CVAE's set-points calibrated against the expert's, row by row of a demonstrations file?

    python benchmarks/studies/prior_calibration.py --data demo-four-lane.h5 --json out/prior_calibration.json \
        [--weights FILE] [--draws 64]

For every row ``train cvae`` would learn from (feasible plan, not in the last 3 s before a
collision), draws ``--draws`` set-point vectors from the CVAE (z ~ N(0, I)) and compares them with
the expert's: mean speed per quarter of the horizon, the median bias of the CVAE's mean, the
within-row spread (speed and lateral, the median over rows) and how often the expert's last speed
set-point lies inside the range drawn; all of it also per band of the ego's speed, since
out-of-distribution states (standing still) are where the pure CVAE start stalls.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import numpy as np

from driveopt.data.demonstrations import DatasetError, load_demonstrations
from driveopt.files import write_json
from driveopt.learned.checkpoint import CheckpointError
from driveopt.learned.cvae import load_cvae, sample_setpoints
from driveopt.priors.cvae import shipped_weights
from driveopt.sim import get_scenario
from driveopt.training.cvae import TrainConfig, training_rows

SPEED_BANDS = ((0.0, 1.0), (1.0, 3.0), (3.0, 6.0), (6.0, 9.0), (9.0, np.inf))  # [m/s] of the ego


def calibration(expert: np.ndarray, drawn: np.ndarray) -> dict:
    """expert (R, 8) and drawn (R, D, 8) set-points -> summary statistics (speeds [m/s], lateral [m])."""
    expert, drawn = expert.astype(np.float64), drawn.astype(np.float64)
    v_expert, v_drawn = expert[:, :4], drawn[..., :4]
    v4 = v_drawn[..., 3]
    return {
        "rows": int(expert.shape[0]),
        "expert_speed_mean": v_expert.mean(0).round(2).tolist(),
        "cvae_speed_mean": v_drawn.mean((0, 1)).round(2).tolist(),
        "cvae_speed_bias_median": np.median(v_drawn.mean(1) - v_expert, 0).round(2).tolist(),
        "cvae_last_speed_spread_median": round(float(np.median(v4.std(1))), 2),
        "cvae_last_lateral_spread_median": round(float(np.median(drawn[..., 7].std(1))), 2),
        "expert_last_speed_inside_drawn_range": round(float(np.mean((expert[:, 3] >= v4.min(1)) & (expert[:, 3] <= v4.max(1)))), 3),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", required=True, help="demonstrations (HDF5) from driveopt collect")
    parser.add_argument("--weights", help="CVAE checkpoint (default: the shipped weights for the data's road)")
    parser.add_argument("--json", default="out/prior_calibration.json")
    parser.add_argument("--draws", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.draws < 2:
        parser.error("--draws must be >= 2")
    try:
        data = load_demonstrations(args.data)
        lanes = {get_scenario(str(name)).lanes for name in data.episodes["scenario"]}
        weights = args.weights or (shipped_weights(lanes.pop()) if len(lanes) == 1 else None)
        if weights is None:
            parser.error("no shipped CVAE weights for the data's road (or roads of several widths); pass --weights")
        cfg, params, norm, _ = load_cvae(weights)
    except (DatasetError, CheckpointError) as exc:
        print(f"prior_calibration: error: {exc}", file=sys.stderr)
        return 2
    rows = training_rows(data, TrainConfig().crash_margin)
    draw = jax.jit(jax.vmap(lambda obs, lanes_, key: sample_setpoints(params, cfg, norm, obs, lanes_, key, args.draws)))
    keys = jax.random.split(jax.random.PRNGKey(args.seed), len(rows))
    drawn = np.asarray(draw(data.observation[rows], data.lane_bounds[rows], keys))
    expert = data.setpoints[rows]
    ego_speed = data.init_x[rows, 1]
    report = {"data": [str(p) for p in args.data], "weights": str(weights), "draws": args.draws,
              "all": calibration(expert, drawn), "by_ego_speed": {}}
    for lo, hi in SPEED_BANDS:
        band = (ego_speed >= lo) & (ego_speed < hi)
        if band.any():
            report["by_ego_speed"][f"{lo:g}-{hi:g}"] = calibration(expert[band], drawn[band])
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, report)
    print(json.dumps(report["all"]))
    for band, stats in report["by_ego_speed"].items():
        print(f"ego {band:>6} m/s: {stats['rows']:5d} rows, expert v4 {stats['expert_speed_mean'][3]:5.2f}, "
              f"CVAE v4 {stats['cvae_speed_mean'][3]:5.2f} (spread {stats['cvae_last_speed_spread_median']:.2f}), "
              f"expert inside drawn range {100 * stats['expert_last_speed_inside_drawn_range']:.0f}%")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
