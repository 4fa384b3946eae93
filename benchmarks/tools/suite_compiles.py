"""Where the test suite's time goes: JAX compilation per test and the planner graphs each test compiles.

A pytest plugin, then a summary of what it wrote:

    COMPILE_STATS_DIR=out/suite PYTHONPATH=. python -m pytest -q -p benchmarks.tools.suite_compiles --durations=0 > out/suite/log
    python benchmarks/tools/suite_compiles.py out/suite [--top 40]

Each test process (an xdist worker, or the main process with ``-n 0``) writes ``compiles-<worker>.json``: for every
test, the seconds of JAX tracing, lowering and backend compilation and the number of backend compilations (from
``jax.monitoring``), and every planner graph the process looked up for the first time (``ExportedCalls``: the test,
the configuration's differences from ``PlannerConfig()``, the strategies and the argument shapes). The summary merges
the workers' files and prints the tests by compile time and the planner graphs with the tests that compiled them:
graphs that differ only in a float of the configuration are the ones a traced configuration would share. Commands
that tests start in subprocesses are not counted.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import sys
from pathlib import Path

COMPILE = "/jax/core/compile/backend_compile_duration"
TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")

_current = ["<collection>"]
_tests: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
_graphs: list[dict] = []


def config_changes(config, default, prefix: str = "") -> list[str]:
    """``section.field=value`` for every field of ``config`` that differs from ``default`` (nested dataclasses)."""
    out = []
    for f in dataclasses.fields(config):
        value, base = getattr(config, f.name), getattr(default, f.name)
        if dataclasses.is_dataclass(value) and dataclasses.is_dataclass(base):
            out += config_changes(value, base, f"{prefix}{f.name}.")
        elif value != base:
            out.append(f"{prefix}{f.name}={value!r}")
    return out


def _listen(event: str, duration: float, **_) -> None:
    counter = _tests[_current[0]]
    if event == COMPILE:
        counter["compile_s"] += duration
        counter["compiles"] += 1
    elif event in TRACE:
        counter["trace_lower_s"] += duration


def pytest_configure(config) -> None:
    import jax

    from driveopt.config import PlannerConfig
    from driveopt.solve_export import ExportedCalls

    jax.monitoring.register_event_duration_secs_listener(_listen)
    load = ExportedCalls._load

    def recording_load(self, static, in_tree, avals):
        planner_config = static.get("config")
        _graphs.append({
            "test": _current[0], "function": getattr(self.fun, "__name__", "?"),
            "config": config_changes(planner_config, PlannerConfig()) if isinstance(planner_config, PlannerConfig) else None,
            "static": {k: repr(v) for k, v in sorted(static.items()) if k != "config"},
            "shapes": sorted({str(tuple(a.shape)) for a in avals}),
        })
        return load(self, static, in_tree, avals)

    ExportedCalls._load = recording_load


def pytest_runtest_logstart(nodeid, location) -> None:
    _current[0] = nodeid


def pytest_sessionfinish(session) -> None:
    folder = Path(os.environ.get("COMPILE_STATS_DIR", "."))
    folder.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    (folder / f"compiles-{worker}.json").write_text(json.dumps({"tests": _tests, "graphs": _graphs}, indent=1))


def summary(folder: Path, top: int) -> str:
    files = sorted(folder.glob("compiles-*.json"))
    if not files:
        raise SystemExit(f"suite_compiles: error: no compiles-*.json in {folder}")
    tests: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    graphs: dict[tuple, list[str]] = collections.defaultdict(list)
    for path in files:
        data = json.loads(path.read_text())
        for name, counts in data["tests"].items():
            tests[name].update(counts)
        for g in data["graphs"]:
            graphs[(g["function"], tuple(g["config"] or ()), tuple(g["static"].items()), tuple(g["shapes"]))].append(g["test"])
    total = collections.Counter()
    for counts in tests.values():
        total.update(counts)
    lines = [f"{len(files)} processes: {total['compiles']} compilations, {total['compile_s']:.0f} s compiling, "
             f"{total['trace_lower_s']:.0f} s tracing and lowering", "", "tests by compile time [s] (compilations):"]
    for name, counts in sorted(tests.items(), key=lambda item: -item[1]["compile_s"])[:top]:
        lines.append(f"{counts['compile_s']:7.1f} ({counts['compiles']:4d})  {name}")
    lines += ["", f"{len(graphs)} planner graphs (first lookup per process):"]
    for (function, changes, static, _), names in sorted(graphs.items(), key=lambda item: item[1][0]):
        strategies = ", ".join(f"{k}={v}" for k, v in static if k != "unroll")
        lines.append(f"- {function} in {len(names)} process(es), first by {names[0]}\n    config: {'; '.join(changes) or 'defaults'}"
                     f"\n    {strategies}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="COMPILE_STATS_DIR of the run")
    parser.add_argument("--top", type=int, default=40, help="tests to list")
    args = parser.parse_args(argv)
    print(summary(args.folder, args.top))
    return 0


if __name__ == "__main__":
    sys.exit(main())
