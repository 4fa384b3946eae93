"""How long the command line takes to start: ``--help``, the listings, and a first and a second ``driveopt plan``.

    python benchmarks/perf/startup.py --json out/startup.json [--runs 5] [--plan-runs 3] [--plan-args ...]

Every command runs in a fresh process (``python -m driveopt.cli``, as the ``driveopt`` script runs it); the time is
the process's wall time [s], the median over ``--runs`` runs (``--plan-runs`` for ``plan``). ``plan`` is timed twice
per run with the same configuration and a compilation-cache folder of its own: ``plan_first`` starts from an empty
folder (it compiles the planner and writes it there), ``plan_second`` finds it there (it loads the compiled planner).
For both, ``first_call_s`` is the first planning call as ``plan --json`` reports it (compilation or loading included),
``solve_s`` the median of the further calls (``--repeats``), and ``start_to_plan_s`` the wall time minus
``--repeats`` x ``solve_s``: from the command's start to the first plan's result, writing the JSON and exiting
included. ``plan_second_once`` is the wall time of the second ``plan`` run again with ``--repeats 0`` and no
``--json``: the whole command, from its start to its exit after one plan. Each run's CPU time (user +
system, all threads) is recorded beside its wall time: on a busy machine it is the better guide to what the command
costs. The machine's load average (``os.getloadavg``) is recorded before and after every measurement.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from driveopt.cli.common import positive_int
from driveopt.files import write_json

LIGHT = {"help": ["--help"], "scenarios": ["scenarios"], "planners": ["planners"], "problems": ["problems"],
         "plan_help": ["plan", "--help"]}
PLAN_ARGS = ["--problem", "dense-snapshot", "--repeats", "3"]


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall time [s], CPU time [s], user + system, of all its threads) of ``driveopt argv`` in a fresh process."""
    cpu, start = _children_cpu_s(), time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "driveopt.cli", *argv], capture_output=True, text=True, env=env,
                          check=False)
    wall, cpu = time.perf_counter() - start, _children_cpu_s() - cpu
    if proc.returncode != 0:
        raise SystemExit(f"startup: driveopt {' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return wall, cpu


def _environment(cache: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    return {**env, "DRIVEOPT_COMPILATION_CACHE": cache}


def time_light(name: str, argv: list[str], runs: int) -> dict:
    """Median wall time of a command that plans nothing (with the cache off: it must not matter)."""
    load = os.getloadavg()
    runs_ = [_run(argv, _environment("0")) for _ in range(runs)]
    walls = [wall for wall, _ in runs_]
    return {"argv": argv, "runs": walls, "median_s": statistics.median(walls),
            "cpu_median_s": statistics.median(cpu for _, cpu in runs_), "load_before": load, "load_after": os.getloadavg()}


def _plan_once(plan_args: list[str], cache: Path, out: Path) -> dict:
    wall, cpu = _run(["plan", *plan_args, "--json", str(out)], _environment(str(cache)))
    timing = json.loads(out.read_text())["timing"]
    repeats = 0 if timing["solve_s"] is None else int(plan_args[plan_args.index("--repeats") + 1])
    return {"wall_s": wall, "cpu_s": cpu, "first_call_s": timing["first_call_s"], "solve_s": timing["solve_s"],
            "start_to_plan_s": wall - repeats * (timing["solve_s"] or 0.0)}


def time_plan(plan_args: list[str], runs: int) -> dict:
    """``plan`` from an empty cache folder, then again from the folder it filled; ``runs`` times, each with a new one."""
    result: dict = {"args": plan_args, "plan_first": [], "plan_second": [], "plan_second_once": [], "cache_entries": [],
                    "load": []}
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="driveopt-startup-") as tmp:
            cache, out = Path(tmp) / "cache", Path(tmp) / "plan.json"
            load = os.getloadavg()
            result["plan_first"].append(_plan_once(plan_args, cache, out))
            result["cache_entries"].append(sorted(p.name.split("-")[0] for p in cache.glob("*-cache")))
            result["plan_second"].append(_plan_once(plan_args, cache, out))
            result["plan_second_once"].append(_run(["plan", *_once(plan_args)], _environment(str(cache)))[0])
            result["load"].append({"before": load, "after": os.getloadavg()})
    for which in ("plan_first", "plan_second"):
        result[f"{which}_median"] = {k: statistics.median(r[k] for r in result[which] if r[k] is not None)
                                     for k in ("wall_s", "cpu_s", "first_call_s", "start_to_plan_s")}
    result["plan_second_once_median_s"] = statistics.median(result["plan_second_once"])
    return result


def _once(plan_args: list[str]) -> list[str]:
    """``plan_args`` with ``--repeats 0``: the command plans once and exits."""
    args = list(plan_args)
    args[args.index("--repeats") + 1] = "0"
    return args


def machine() -> dict:
    return {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "jax": importlib.metadata.version("jax")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default="out/startup.json", help="results file")
    parser.add_argument("--runs", type=positive_int, default=5, help="runs of each light command (--help, listings)")
    parser.add_argument("--plan-runs", type=positive_int, default=3, help="first/second plan pairs")
    parser.add_argument("--plan-args", nargs=argparse.REMAINDER, default=PLAN_ARGS,
                        help=f"arguments of driveopt plan, last on the line (default: {' '.join(PLAN_ARGS)}); "
                             "must include --repeats")
    args = parser.parse_args(argv)
    if "--repeats" not in args.plan_args:
        parser.error("--plan-args must include --repeats N")
    report: dict = {"machine": machine(), "load_before": os.getloadavg(), "commands": {}}
    for name, command in LIGHT.items():
        report["commands"][name] = time_light(name, command, args.runs)
        record = report["commands"][name]
        print(f"driveopt {' '.join(command)}: {record['median_s']:.2f} s wall, {record['cpu_median_s']:.2f} s CPU, median of "
              f"{args.runs}", flush=True)
    report["plan"] = time_plan(args.plan_args, args.plan_runs)
    for which in ("plan_first", "plan_second"):
        m = report["plan"][f"{which}_median"]
        print(f"{which}: {m['wall_s']:.2f} s wall ({m['cpu_s']:.2f} s CPU), first call {m['first_call_s']:.2f} s, start to first plan "
              f"{m['start_to_plan_s']:.2f} s (median of {args.plan_runs})", flush=True)
    print(f"plan_second with --repeats 0 and no --json, the whole command: {report['plan']['plan_second_once_median_s']:.2f} s "
          f"wall (median of {args.plan_runs})", flush=True)
    report["load_after"] = os.getloadavg()
    path = write_json(args.json, report)  # strict JSON, whole or not at all
    print(f"wrote {path} (load average {report['load_before'][0]:.2f} before, {report['load_after'][0]:.2f} after)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
