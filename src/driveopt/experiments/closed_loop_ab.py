"""Does a change keep closed-loop episodes bit for bit? The same episodes under another source tree and this one
(``driveopt closed-loop-ab``).

A refactor that claims to leave planning unchanged keeps every record measured before it valid only if the episodes
are identical, not just statistically alike: one differing float diverges an episode within seconds. Each side runs
in its own process with its tree's ``src`` first on ``PYTHONPATH`` (the baseline: e.g. the ``src`` of a ``git
worktree`` at the old commit; the current side: the folder this driveopt package is imported from), every run one
episode of driveopt's closed loop (``run_episode``). :func:`compare_trees` returns, per run, whether speeds, lateral
positions and statuses are identical, the first step where they differ, and each side's ``compile_seconds`` (the
driver's warm-up before the timed steps).

A side's process runs this file as a script (``python .../closed_loop_ab.py SETTINGS``), not as a module of the
package: the baseline's ``driveopt`` may predate this module, so the side's code imports nothing of driveopt but what
it runs (``run_episode``, ``get_planner``), from whichever tree is first on its path. Each side's file
(``NAME.baseline.json``, ``NAME.current.json`` beside the output) is written after every run, and a rerun skips what
it holds: an interrupted comparison resumes.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

# planner:scenario; every learned planner on P2's dense traffic, the others on a road of their own (closed-loop
# warm start and previous plan: bilevel, cvae-mix; the grid baseline: one sampler iteration)
RUNS = ("bilevel:four-lane-d3.0", "cvae-mix:four-lane-d3.0", "vqvae-cem:p2-four-lane-d3.0", "vqvae:p2-four-lane-d3.0",
        "cvae-filter:p2-four-lane-d3.0", "vqvae-filter:p2-four-lane-d3.0", "grid:two-lane-d2.0")
SIDES = ("baseline", "current")


def split_run(run: str) -> tuple[str, str]:
    """(planner, scenario) of a ``planner:scenario`` run; ValueError for any other shape."""
    parts = run.split(":")
    if len(parts) != 2 or not all(parts):
        raise ValueError(f"a run is planner:scenario, got {run!r}")
    return parts[0], parts[1]


def side_files(out: Path, current_config: dict | None = None) -> dict[str, Path]:
    """Where each side keeps its episodes: ``NAME.baseline.json`` and ``NAME.current.json`` beside ``out`` (with
    ``current_config``: ``NAME.current-DIGEST.json``, so that a rerun with other overrides resumes none of them)."""
    files = {side: out.with_name(f"{out.stem}.{side}.json") for side in SIDES}
    if current_config:
        text = json.dumps(current_config, sort_keys=True, separators=(",", ":"))
        files["current"] = out.with_name(f"{out.stem}.current-{hashlib.sha256(text.encode()).hexdigest()[:16]}.json")
    return files


def this_tree() -> Path:
    """The folder this driveopt package is imported from (a checkout's ``src``, or site-packages): the current side's
    first entry on ``PYTHONPATH``."""
    return Path(__file__).resolve().parents[2]


def run_side(runs: Sequence[str], seed: int, duration: float, path: Path, log: Callable[[str], None] = print,
             config: dict | None = None) -> None:
    """Run each ``planner:scenario`` episode not yet in ``path`` in this process (the code of the driveopt first on
    the path), each planner with the planner-config overrides ``config`` where given, and add it there, the file
    rewritten after every run."""
    try:
        from driveopt.experiments.rollout import run_episode
    except ModuleNotFoundError:  # a tree whose episode loop lives in sim/
        from driveopt.sim.rollout import run_episode
    from driveopt.registry import get_planner

    done = json.loads(path.read_text()) if path.exists() else {}
    for run in runs:
        if run in done:
            continue
        planner, scenario = split_run(run)
        spec = get_planner(planner)
        episode = run_episode(scenario, spec.with_overrides(**config) if config else spec, seed=seed, duration=duration)
        done[run] = {"speeds": [float(v) for v in episode.speeds], "lateral": [float(v) for v in episode.lateral],
                     "statuses": dict(episode.statuses), "compile_seconds": episode.compile_seconds}
        partial = path.with_name(path.name + ".partial")  # whole or not at all: a stopped side keeps its file
        partial.write_text(json.dumps(done))
        os.replace(partial, path)
        log(f"  {run}: {len(episode.speeds)} steps, compile {episode.compile_seconds:.1f} s")


def first_difference(a: dict, b: dict) -> int | None:
    """The first step at which two episodes' speeds or lateral positions differ (None: identical, same length)."""
    for step, pair in enumerate(zip(zip(a["speeds"], a["lateral"]), zip(b["speeds"], b["lateral"]))):
        if pair[0] != pair[1]:
            return step
    return None if len(a["speeds"]) == len(b["speeds"]) else min(len(a["speeds"]), len(b["speeds"]))


def compare(baseline: dict, current: dict) -> dict:
    """Per run of ``baseline``: identical (speeds, lateral positions and statuses), the first differing step, the
    current side's step count and both sides' compile seconds."""
    rows = {}
    for run in baseline:
        step = first_difference(baseline[run], current[run])
        identical = step is None and baseline[run]["statuses"] == current[run]["statuses"]
        rows[run] = {"identical": identical, "first_difference_step": step, "steps": len(current[run]["speeds"]),
                     "compile_seconds": {"baseline": baseline[run]["compile_seconds"], "current": current[run]["compile_seconds"]}}
    return rows


class SideFailed(RuntimeError):
    """A side's process ended with an error (its own output says which)."""


def compare_trees(baseline_src: Path, out: Path, runs: Sequence[str] = RUNS, *, seed: int = 5, duration: float = 8.0,
                  current_config: dict | None = None, log: Callable[[str], None] = print) -> dict:
    """Run ``runs`` under ``baseline_src`` and under this tree, each side in its own process, and write the comparison
    (:func:`compare`, with the settings) to ``out``; returns its rows. ``current_config``: planner-config overrides of
    this tree's side alone (a default changed since, named here as it was). Both sides resume from their files beside
    ``out``. ValueError for a malformed run; :class:`SideFailed` when a side's process fails."""
    for run in runs:
        split_run(run)
    out.parent.mkdir(parents=True, exist_ok=True)
    files = side_files(out, current_config)
    for side, src in (("baseline", baseline_src.resolve()), ("current", this_tree())):
        log(f"{side}: {src}")
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(src), os.environ.get("PYTHONPATH")]))}
        settings = json.dumps({"runs": list(runs), "seed": seed, "duration": duration,
                               "config": current_config if side == "current" else None})
        status = subprocess.run([sys.executable, __file__, settings, str(files[side])], env=env).returncode
        if status != 0:
            raise SideFailed(f"the {side} side ({src}) stopped with status {status}")
    results = {side: json.loads(path.read_text()) for side, path in files.items()}
    rows = compare({run: results["baseline"][run] for run in runs}, {run: results["current"][run] for run in runs})
    out.write_text(json.dumps({"seed": seed, "duration": duration, "baseline_src": str(baseline_src),
                               "current_config": current_config, "runs": rows}, indent=1))
    return rows


if __name__ == "__main__":  # one side: python closed_loop_ab.py SETTINGS_JSON SIDE_FILE
    del sys.path[0]  # this file's folder: its modules are the package's, not top-level ones
    side_settings = json.loads(sys.argv[1])
    try:
        run_side(side_settings["runs"], side_settings["seed"], side_settings["duration"], Path(sys.argv[2]),
                 log=lambda line: print(line, flush=True), config=side_settings.get("config"))
    except KeyboardInterrupt:  # Ctrl-C reaches both processes; the parent reports it
        sys.exit(130)
