"""``driveopt commonroad``'s runner: every scenario of a folder x every planner, one JSONL record per run, resumable.

OUT holds ``runs.jsonl`` (one line per finished run, flushed and fsynced as it ends; a rerun skips the runs it holds, a
last line cut short by a crash is dropped), ``trajectories/SCENARIO__PLANNER.json`` (the executed poses: step, x, y,
yaw [rad], speed [m/s]) and ``summary.md``. A record holds: scenario, planner, execution, status (success, collision,
collision_while_stopped, off_road, timeout, refused), goal_reached, collision, collision_while_stopped, off_road,
arrival_step, steps, plan_ms_median, plan_ms_p95 [ms] and plan_status_counts; a ``tracked`` run also holds
tracking_m_median and tracking_m_max [m] (how far the car ended each step from where the followed plan was then); a
refused scenario holds its reason.

One folder holds one execution model (:data:`~driveopt.commonroad.EXECUTIONS`): a run with another model than its
records' is refused in one line (:func:`check_execution`), as is ``tracked`` for FISS's planners, which FISS's own
closed loop moves perfectly along their plans (their plans are not handed back step by step to be tracked).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Callable

from driveopt.errors import DriveoptError
from driveopt.files import atomic_write, json_text

RUNS_FILE = "runs.jsonl"


def scenario_files(folder: str | Path) -> list[Path]:
    """The ``.xml`` files of ``folder``, sorted; DriveoptError (one line) for a missing or empty folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DriveoptError(f"--scenarios {folder}: not a folder")
    files = sorted(folder.glob("*.xml"))
    if not files:
        raise DriveoptError(f"--scenarios {folder}: holds no CommonRoad .xml file")
    return files


def load_runs(path: Path) -> list[dict[str, Any]]:
    """The records of ``runs.jsonl`` (a last line without its newline, cut short by a crash, is dropped)."""
    if not path.exists():
        return []
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        data = data[: data.rfind(b"\n") + 1]
        atomic_write(path, data)
    records = []
    for number, line in enumerate(data.decode("utf-8").splitlines(), 1):
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            raise DriveoptError(f"{path}:{number}: not a JSON record") from None
    return records


def _append(path: Path, record: dict[str, Any]) -> None:
    with open(path, "a", encoding="utf-8") as f:
        f.write(json_text(record, indent=None) + "\n")
        f.flush()
        os.fsync(f.fileno())


def check_execution(execution: str, planners: tuple[str, ...], records: list[dict[str, Any]], out: str | Path) -> None:
    """DriveoptError (one line) for an unknown ``execution``, ``tracked`` asked of a FISS planner, or ``out``'s
    ``records`` made with another execution model (a record without one was made with ``perfect``, the only one then)."""
    from driveopt.commonroad import EXECUTIONS
    from driveopt.commonroad.fiss import PLANNERS as FISS

    if execution not in EXECUTIONS:
        raise DriveoptError(f"--execution {execution!r}: not one of {', '.join(EXECUTIONS)}")
    fiss = [p for p in planners if p in FISS]
    if execution != "perfect" and fiss:
        raise DriveoptError(f"--execution {execution}: {', '.join(fiss)} run in FISS's own closed loop, which moves the "
                            "ego perfectly along each plan; only driveopt's planners can be tracked (use --execution "
                            "perfect for FISS)")
    found = sorted({r.get("execution", "perfect") for r in records} - {execution})
    if found:
        raise DriveoptError(f"{out} holds runs with --execution {', '.join(found)}; one folder holds one execution model: "
                            f"give --execution {found[0]} to resume it, or another --out for {execution}")


def run(folder: str | Path, planners: tuple[str, ...], out: str | Path, samples: int | None = None,
        execution: str = "perfect", log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Run what ``runs.jsonl`` lacks; return every record, in scenario and planner order."""
    from driveopt.commonroad.drive import drive
    from driveopt.commonroad.fiss import PLANNERS as FISS, drive_fiss
    from driveopt.commonroad.world import CommonRoadWorld, UnsupportedScenario

    files = scenario_files(folder)
    out = Path(out)
    path = out / RUNS_FILE
    held = load_runs(path)
    check_execution(execution, planners, held, out)
    done = {(r["scenario"], r["planner"]) for r in held}
    (out / "trajectories").mkdir(parents=True, exist_ok=True)
    for file in files:
        todo = [p for p in planners if (file.stem, p) not in done]
        if not todo:
            continue
        try:
            world = CommonRoadWorld(file)
        except UnsupportedScenario as exc:
            for planner in todo:
                _append(path, {"scenario": file.stem, "planner": planner, "execution": execution, "status": "refused",
                               "goal_reached": False, "reason": str(exc)})
            log(f"refused: {exc}")
            continue
        for planner in todo:
            if planner in FISS:
                record, poses = drive_fiss(world, planner)
            else:
                record, poses = drive(world, planner, samples=samples, execution=execution)
            atomic_write(out / "trajectories" / f"{file.stem}__{planner}.json",
                         json_text([[p.step, p.x, p.y, p.yaw, p.speed] for p in poses], indent=None).encode())
            _append(path, record)
            log(f"{file.stem} {planner}: {record['status']} (median plan {record['plan_ms_median']:.1f} ms)")
    order = {(f.stem, p): i for i, (f, p) in enumerate((f, p) for f in files for p in planners)}
    records = sorted((r for r in load_runs(path) if (r["scenario"], r["planner"]) in order),
                     key=lambda r: order[(r["scenario"], r["planner"])])
    atomic_write(out / "summary.md", summary_table(records).encode())
    return records


def summary_table(records: list[dict[str, Any]]) -> str:
    """Markdown: one row per planner and execution model (successes, collisions, of them while stopped, off road,
    timeouts, refused, median and p95 plan time over the runs' medians and p95s), then one row per run."""
    planners = list(dict.fromkeys((r["planner"], r.get("execution", "perfect")) for r in records))
    lines = ["| planner | execution | runs | success | collision (while stopped) | off road | timeout | refused | "
             "plan ms median | plan ms p95 |", "|---|---|---|---|---|---|---|---|---|---|"]
    for planner, execution in planners:
        rows = [r for r in records if r["planner"] == planner and r.get("execution", "perfect") == execution]
        count = lambda status: sum(r["status"] == status for r in rows)  # noqa: E731
        medians = sorted(r["plan_ms_median"] for r in rows if r.get("plan_ms_median") is not None)
        p95 = sorted(r["plan_ms_p95"] for r in rows if r.get("plan_ms_p95") is not None)
        mid = lambda v: f"{v[len(v) // 2]:.1f}" if v else "-"  # noqa: E731
        lines.append(f"| {planner} | {execution} | {len(rows)} | {count('success')} | "
                     f"{count('collision') + count('collision_while_stopped')} ({count('collision_while_stopped')}) | "
                     f"{count('off_road')} | {count('timeout')} | {count('refused')} | {mid(medians)} | {mid(p95)} |")
    lines += ["", "| scenario | planner | execution | status | arrival step | plan ms median | plan ms p95 |",
              "|---|---|---|---|---|---|---|"]
    for r in records:
        fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        lines.append(f"| {r['scenario']} | {r['planner']} | {r.get('execution', 'perfect')} | {r['status']} | {r.get('arrival_step') or '-'} | "
                     f"{fmt(r.get('plan_ms_median'))} | {fmt(r.get('plan_ms_p95'))} |")
    return "\n".join(lines) + "\n"
