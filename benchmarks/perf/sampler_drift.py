"""Where the sampler's distribution goes against where its picks are, with and without a projection setting, on the
recorded closed-loop states of the tests:

    python benchmarks/perf/sampler_drift.py --set early_iterations=6 [--keys 4] [--states N] [--json OUT]

At each state the registered ``bilevel``'s planner (its 150 samples and real-time projection) plans under ``--keys``
keys with its own configuration and with the ``--set`` projection fields changed. Recorded per side, averaged over
states and keys: the mean speed set-point [m/s] of the first batch's elites and of its feasible rows, how many rows of
it are feasible, the share of the first update's weight (P1 eq. 6) its infeasible elites hold, the final sampling
mean's speed and the pick's speed [m/s] (each speed the mean of the four set-points).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a file: the repository root on the path, for the package imports
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

STATES = Path(__file__).resolve().parents[2] / "tests" / "core" / "closed-loop-states.npz"
FIELDS = ("first_elites_speed", "first_feasible_speed", "first_feasible_rows", "first_infeasible_elite_weight",
          "final_mean_speed", "pick_speed")


def side_figures(problem, config, keys: int, offset: int) -> dict[str, float]:
    """The FIELDS of one state and configuration, averaged over ``keys`` keys."""
    import jax
    import numpy as np

    from driveopt import plan
    from driveopt.method import DRIVEOPT_METHOD
    from driveopt.sampler import elite_weights

    rows = []
    for k in range(keys):
        result = plan(problem, config, key=jax.random.PRNGKey(offset + k))
        first = result.first
        setpoints, residual, elites = np.asarray(first.setpoints), np.asarray(first.residual), np.asarray(first.elite_index)
        feasible = residual <= config.sampler.residual_tolerance
        score = DRIVEOPT_METHOD.ranking.score(np.asarray(first.cost)[elites], residual[elites])
        weights = np.asarray(elite_weights(score, config.sampler.temperature))
        rows.append((setpoints[elites, :4].mean(), setpoints[feasible, :4].mean() if feasible.any() else np.nan,
                     feasible.sum(), weights[~feasible[elites]].sum(), np.asarray(result.mean)[:4].mean(),
                     np.asarray(result.setpoints)[:4].mean()))
    return dict(zip(FIELDS, np.nanmean(np.asarray(rows, float), axis=0).tolist()))


def main(argv=None) -> int:
    from benchmarks.perf.op_count import _setting
    from benchmarks.perf.settings_offline import load_states

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--set", type=_setting, action="append", required=True, metavar="FIELD=VALUE",
                        help="a projection field of the changed side (repeatable)")
    parser.add_argument("--keys", type=int, default=4, help="keys per state and side")
    parser.add_argument("--states", type=int, help="only the first this many states")
    parser.add_argument("--json", type=Path, help="results file")
    args = parser.parse_args(argv)
    if args.keys < 1 or (args.states is not None and args.states < 1):
        parser.error("--keys and --states must be >= 1")

    import jax
    import jax.numpy as jnp
    import numpy as np

    from driveopt.errors import DriveoptError
    from driveopt.files import write_json
    from driveopt.registry import get_optimiser

    own = get_optimiser("bilevel").config
    try:
        sides = {"own": own, "changed": own.replace(projection=dict(args.set))}
    except DriveoptError as exc:  # an unknown field or a bad value
        parser.error(str(exc))
    states = []
    for index, (_, problem) in enumerate(load_states(STATES)):
        if args.states is not None and index >= args.states:
            break
        problem = jax.tree_util.tree_map(jnp.asarray, problem)
        states.append({side: side_figures(problem, config, args.keys, 100 * index) for side, config in sides.items()})
        print(f"state {index}: " + ", ".join(f"{side} pick {s['pick_speed']:.2f} m/s, final mean {s['final_mean_speed']:.2f}"
                                             for side, s in states[-1].items()), flush=True)
    summary = {side: {field: float(np.nanmean([s[side][field] for s in states])) for field in FIELDS} for side in sides}
    for side, figures in summary.items():
        print(side, ", ".join(f"{field} {value:.2f}" for field, value in figures.items()))
    if args.json:
        write_json(args.json, {"command": "python benchmarks/perf/sampler_drift.py " + " ".join(argv or sys.argv[1:]),
                               "changed": dict(args.set), "keys": args.keys, "states": states, "summary": summary})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
