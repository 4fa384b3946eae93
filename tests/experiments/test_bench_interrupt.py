"""A real ``driveopt bench`` process (tests/bench_child.py: fake episodes that sleep, two spawned workers, or Ray
tasks) interrupted by Ctrl-C or SIGTERM, or killed with SIGKILL: it stops at once, keeps every finished episode,
resumes, and leaves no worker (no Ray process) behind; a Ctrl-C never reaches a worker, not even one still starting."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from driveopt.experiments.store import load_records

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")

CHILD = Path(__file__).with_name("bench_child.py")
STARTUP_S = 180  # imports and two spawned workers on a loaded machine
PROMPT_S = 10  # a stop or a worker's end, once asked for
FAST = 3  # episodes 0..2 of each planner take 0.1 s, the others a minute: 6 finish, then both workers are busy


def start_child(script: Path, argv: list[str], marks: Path, slow: float) -> subprocess.Popen:
    """``script`` (a job with bench_child.py's fake episodes) started as a script's background job would be."""
    marks.mkdir(exist_ok=True)
    env = {**os.environ, "BENCH_CHILD_SLOW": str(slow), "BENCH_CHILD_FAST": str(FAST), "BENCH_CHILD_MARKS": str(marks)}
    # Its own session, so that a signal to its process group is a Ctrl-C in its terminal; started with
    # SIGINT ignored, as a script's background job (CI's, say) would start it: Ctrl-C must stop it all the same.
    return subprocess.Popen([sys.executable, str(script), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True, preexec_fn=_ignore_sigint)


def start_bench(out: Path, marks: Path, *, slow: float, episodes: int = 8) -> subprocess.Popen:
    return start_child(CHILD, ["--scenarios", "two-lane-d1.0", "--planners", "idm", "grid", "--episodes", str(episodes),
                               "--workers", "2", "--out", str(out)], marks, slow)


def interrupt(proc: subprocess.Popen, how: str) -> None:
    if how == "ctrl-c":
        os.killpg(proc.pid, signal.SIGINT)  # the terminal sends it to every process of the group
    else:
        proc.send_signal(signal.SIGTERM)


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def wait_for(condition, timeout: float, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if proc is not None and proc.poll() is not None:
            pytest.fail(f"the bench ended early ({proc.returncode}): {proc.communicate()[1][-2000:]}")
        if time.monotonic() > deadline:
            pytest.fail("timed out")
        time.sleep(0.1)


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie has ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z"


def workers(parent: int) -> list[int]:
    """The parent's spawned worker processes (PPid in /proc; the resource tracker is not one)."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            fields = (entry / "stat").read_text().rpartition(")")[2].split()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:  # not a process, or it ended
            continue
        if int(fields[1]) == parent and b"spawn_main" in cmdline:
            found.append(int(entry.name))
    return found


def busy_workers(marks: Path, parent: int) -> list[int]:
    """Workers of ``parent`` that have started an episode."""
    return sorted(set(workers(parent)) & {int(p.name) for p in marks.iterdir()})


def reap(proc: subprocess.Popen, pids: list[int]) -> None:
    """Kill what a failed test leaves behind: the bench and its workers (all started here)."""
    for pid in [proc.pid, *pids]:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    proc.wait()


def test_workers_die_with_a_killed_parent(tmp_path):
    # episodes beyond FAST take two minutes: both workers end up in one (with episodes <= FAST the bench could
    # finish before the test saw them busy)
    proc = start_bench(tmp_path / "out", tmp_path / "marks", slow=120, episodes=FAST + 1)
    pids: list[int] = []
    try:
        wait_for(lambda: len(busy_workers(tmp_path / "marks", proc.pid)) == 2, STARTUP_S, proc)
        pids = busy_workers(tmp_path / "marks", proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=PROMPT_S)
        wait_for(lambda: not any(alive(pid) for pid in pids), PROMPT_S)
    finally:
        reap(proc, pids)


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_interrupted_bench_stops_at_once_keeps_episodes_and_resumes(tmp_path, how):
    out, marks = tmp_path / "out", tmp_path / "marks"
    proc = start_bench(out, marks, slow=60)
    pids: list[int] = []
    try:
        wait_for(lambda: len(load_records(out / "episodes.jsonl")) == 2 * FAST, STARTUP_S, proc)
        wait_for(lambda: len(busy_workers(marks, proc.pid)) == 2, STARTUP_S, proc)  # both in a minute-long episode
        time.sleep(0.5)
        pids = workers(proc.pid)
        start = time.monotonic()
        interrupt(proc, how)
        _, stderr = proc.communicate(timeout=PROMPT_S)
        assert time.monotonic() - start < PROMPT_S
        wait_for(lambda: not any(alive(pid) for pid in pids), PROMPT_S)
    finally:
        reap(proc, pids)
    assert "Traceback" not in stderr
    status, word = (130, "interrupted") if how == "ctrl-c" else (128 + signal.SIGTERM, "terminated")
    assert proc.returncode == status
    assert stderr.rstrip().splitlines()[-1] == (
        f"driveopt: {word}: {2 * FAST} episodes kept in {out}; rerun the same command to resume")
    kept = load_records(out / "episodes.jsonl")
    assert len(kept) == 2 * FAST and not (out / "summary.csv").exists()

    rerun = start_bench(out, marks, slow=0)
    _, stderr = rerun.communicate(timeout=STARTUP_S)
    assert rerun.returncode == 0, stderr[-2000:]
    records = load_records(out / "episodes.jsonl")
    keys = [(r["planner"], r["episode"]) for r in records]
    assert records[: len(kept)] == kept and len(keys) == len(set(keys)) == 16
    assert (out / "summary.csv").exists()


def ctrl_c_reaches(pid: int) -> bool:
    """Whether SIGINT would interrupt ``pid`` now: neither blocked nor ignored (/proc/PID/status)."""
    fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    bit = 1 << (signal.SIGINT - 1)
    return not (int(fields["SigBlk"], 16) | int(fields["SigIgn"], 16)) & bit


def test_ctrl_c_while_the_workers_start_stops_the_bench_and_never_reaches_them(tmp_path):
    # a terminal's Ctrl-C goes to every process of the group: a worker still importing must not take it (a traceback)
    marks = tmp_path / "marks"
    proc = start_bench(tmp_path / "out", marks, slow=60)
    pids: list[int] = []
    try:
        wait_for(lambda: len(workers(proc.pid)) == 2, STARTUP_S, proc)
        pids = workers(proc.pid)
        assert not any(ctrl_c_reaches(pid) for pid in pids)
        interrupt(proc, "ctrl-c")
        _, stderr = proc.communicate(timeout=PROMPT_S)
        wait_for(lambda: not any(alive(pid) for pid in pids), PROMPT_S)
    finally:
        reap(proc, pids)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr[-3000:]
    assert stderr.rstrip().splitlines()[-1].startswith("driveopt: interrupted: ")


def descendants(parent: int) -> list[int]:
    """Every process ``parent`` started, and those they started (PPid in /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
        except OSError:  # it ended
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [parent]
    while todo:
        started = children.get(todo.pop(), [])
        found += started
        todo += started
    return found


@pytest.mark.slow  # a local Ray instance takes 10-30 s to start on two cores
@pytest.mark.parametrize("how", ["ctrl-c", "sigterm", "kill -9"])
def test_a_stopped_ray_bench_takes_its_local_ray_instance_with_it(tmp_path, how):
    pytest.importorskip("ray")
    out = tmp_path / "out"
    proc = start_child(CHILD, ["--scenarios", "two-lane-d1.0", "--planners", "idm", "grid", "--episodes", "8",
                               "--backend", "ray", "--out", str(out)], tmp_path / "marks", slow=60)
    ray_processes: list[int] = []
    try:
        wait_for(lambda: len(load_records(out / "episodes.jsonl")) == 2 * FAST, STARTUP_S, proc)
        time.sleep(1.0)  # both slow episodes under way
        ray_processes = descendants(proc.pid)
        assert len(ray_processes) >= 4  # GCS, raylet, agents, workers
        start = time.monotonic()
        if how == "kill -9":
            proc.kill()
        else:
            interrupt(proc, how)
        _, stderr = proc.communicate(timeout=PROMPT_S)
        exit_s = time.monotonic() - start
        wait_for(lambda: not any(alive(pid) for pid in ray_processes), PROMPT_S)
    finally:
        reap(proc, ray_processes)
    if how != "kill -9":
        word, status = ("interrupted", 130) if how == "ctrl-c" else ("terminated", 128 + signal.SIGTERM)
        assert proc.returncode == status and exit_s < 3.0, stderr[-3000:]
        assert stderr.rstrip().splitlines()[-1] == (
            f"driveopt: {word}: {2 * FAST} episodes kept in {out}; rerun the same command to resume")
        assert "Traceback" not in stderr and "SIGTERM received" not in stderr
