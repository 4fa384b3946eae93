"""Planning time of P2's one-pass pipeline against its filter iterations: learned filter against plain.

    python benchmarks/perf/filter_timing.py --json out/filter_timing.json [--iterations 0 10 25 50 100] [--calls 30]
        [--samples 1000] [--problem dense-snapshot] [--filter-weights FILE] [--vqvae-weights FILE] [--learned-config overrides.json]

For each filter iteration count k (``projection.max_iterations``) the plain barrier filter (``vqvae``) and the learned
one (``vqvae-filter``) are compiled on one problem (the built-in 10-neighbour ``dense-snapshot`` by default), each with
the planners' own settings otherwise (so their early stop too, as in closed loop). Then every case is called once per
round, round-robin, ``--calls`` rounds with fresh PRNG keys, so that drift of the machine's speed hits all cases alike.
Reported per case: compile time (first call minus the steady-state median) and the steady-state median and p90 of a
full ``plan()`` call [ms]; and for each k, the learned filter's median as a share of the plain filter's at
``--reference`` iterations (100).
``--learned-config`` applies planner-config overrides (the JSON of ``driveopt plan --config``) to the learned filter's
cases only, before the iteration count (e.g. ``{"projection": {"tolerance": 0.01}}``: a variant of the learned
pipeline against the plain filter as it is). The JSON is written once the compile phase ends and
again at the end.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from driveopt.cli.common import config_overrides
from driveopt.errors import DriveoptError
from driveopt.files import write_json
from driveopt.planner import plan
from driveopt.problem import build_problem
from driveopt.registry import get_optimiser
from driveopt.scene import load_scene

PLANNERS = (("plain", "vqvae"), ("learned", "vqvae-filter"))


def _write(path: Path, report: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, report)  # strict JSON, whole or not at all


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default="out/filter_timing.json", help="results file")
    parser.add_argument("--iterations", type=int, nargs="+", default=[0, 10, 25, 50, 100], help="filter iterations k")
    parser.add_argument("--reference", type=int, default=100, help="the plain filter's iterations the shares are of")
    parser.add_argument("--calls", type=int, default=30, help="round-robin rounds (steady-state calls per case)")
    parser.add_argument("--samples", type=int, default=1000, help="samples per call (P2: 1000)")
    parser.add_argument("--problem", default="dense-snapshot", help="built-in problem or problem JSON file")
    parser.add_argument("--filter-weights", help="learned-filter checkpoint (default: shipped for the road)")
    parser.add_argument("--vqvae-weights", help="PixelCNN checkpoint (default: shipped for the road)")
    parser.add_argument("--learned-config", help="planner-config overrides (JSON) for the learned filter's cases")
    args = parser.parse_args(argv)
    try:
        if args.calls < 1 or args.samples < 1 or min(args.iterations) < 0:
            raise DriveoptError("--calls and --samples must be at least 1 and --iterations at least 0")
        if args.reference not in args.iterations:
            raise DriveoptError(f"--reference {args.reference} must be one of --iterations {args.iterations}")
        report = run(args)
    except DriveoptError as exc:
        print(f"filter_timing: error: {exc}", file=sys.stderr)
        return 2
    reference = report["cases"][f"plain-{args.reference}"]["median_ms"]
    for k in args.iterations:
        learned, plain = (report["cases"][f"{v}-{k}"] for v in ("learned", "plain"))
        print(f"k = {k:3d}: plain {plain['median_ms']:6.1f} ms (compile {plain['compile_s']:.1f} s), learned "
              f"{learned['median_ms']:6.1f} ms (compile {learned['compile_s']:.1f} s) = "
              f"{100 * learned['median_ms'] / reference:.1f}% of plain at {args.reference}")
    print(f"wrote {args.json}")
    return 0


def run(args: argparse.Namespace) -> dict:
    overrides = config_overrides(args.learned_config)
    scene = load_scene(args.problem)
    lanes = scene.road.num_lanes
    cases = {}
    for k in args.iterations:
        for variant, name in PLANNERS:
            spec = get_optimiser(name).with_weights(args.vqvae_weights).with_samples(args.samples)
            if variant == "learned":
                weights = {"safety_filter": {"weights": args.filter_weights}} if args.filter_weights else {}
                spec = spec.with_overrides(**{**overrides, **weights})  # --filter-weights wins over the overrides'
            spec = spec.with_overrides(projection={"max_iterations": k})
            problem = build_problem(scene, spec.config.basis, braking_time=spec.braking_time,
                                    selection_time=spec.selection_time)
            cases[f"{variant}-{k}"] = dict(config=spec.config, prior=spec.prior(lanes), safety_filter=spec.safety_filter(lanes),
                                           problem=problem, method=spec.method)

    def call(case: dict, key: int) -> float:
        start = time.perf_counter()
        plan(case["problem"], case["config"], key=jax.random.PRNGKey(key), prior=case["prior"],
             safety_filter=case["safety_filter"], x_offset=scene.ego.x, method=case["method"])
        return time.perf_counter() - start

    first = {name: call(case, 0) for name, case in tqdm(cases.items(), desc="compile", unit="case")}
    report = {"problem": scene.name, "samples": args.samples, "learned_config": overrides, "calls": args.calls,
              "reference": args.reference,
              "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "jax": jax.__version__,
                          "backend": jax.default_backend()},
              "cases": {name: {"first_call_s": t} for name, t in first.items()}}
    _write(Path(args.json), report)
    times: dict[str, list[float]] = {name: [] for name in cases}
    for i in tqdm(range(args.calls), desc="round-robin", unit="round"):
        for name, case in cases.items():
            times[name].append(call(case, i + 1))
    for name, ts in times.items():
        median = float(np.median(ts))
        report["cases"][name].update(median_ms=1e3 * median, p90_ms=1e3 * float(np.percentile(ts, 90)),
                                     compile_s=max(first[name] - median, 0.0))
    reference = report["cases"][f"plain-{args.reference}"]["median_ms"]
    report["share_of_reference"] = {name: c["median_ms"] / reference for name, c in report["cases"].items()}
    _write(Path(args.json), report)
    return report


if __name__ == "__main__":
    sys.exit(main())
