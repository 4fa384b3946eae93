"""A signal at any moment of a ``driveopt`` command ends it with 130 / 143 and exactly one line on stderr, never with a
crash (``Fatal Python error``, a traceback) or Python's default handling (status -2 / -15): in each window of its life.

Windows, each aimed by what the child process shows (this file run as a script is the real ``driveopt`` program,
``main()`` without arguments, with marks on stderr):

* ``start``: as soon as ``main`` has installed its handlers (SIGTERM appears among the caught signals in
  ``/proc/PID/status``), while it parses and imports;
* ``compile``: inside XLA's first compilation of the planner (the compilation cache off, so that there is one), where
  a signal stops XLA mid-compilation and the process has pygame loaded for the commands that simulate;
* ``run``: once the first plan has returned, while the command plans and simulates;
* ``end``: after the command's last output, while the process ends (``DRIVEOPT_EXIT_PAUSE_S`` holds it there for
  :data:`END_PAUSE_S`; the signals are spread over the pause).

The default run sends a few signals on the cheapest commands (``plan`` on a small problem, ``collect`` of one short
episode), all processes at once. The ``slow`` tests repeat each window :data:`REPEATS` times per command (default 60:
a failure that occurs once in 20 signals is caught with probability 1 - 0.95**60 = 95 %) on ``plan``, ``drive``,
``bench`` (one worker and two) and ``collect``; ``DRIVEOPT_EXIT_REPEATS`` changes the count, and each case prints
its outcomes and the longest time from signal to exit.
"""

import itertools
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="POSIX signals, /proc")

CHILD = Path(__file__).resolve()
MARK = "exit-window-child:"
PAUSE_LINE = "pausing before exit (DRIVEOPT_EXIT_PAUSE_S)"
END_PAUSE_S = 1.0  # [s] the child's pause after its last output
REACH_S = 600  # [s] the most a child may take to reach its mark and end (compilation on a loaded 2-core machine)
EXIT_LIMIT_S = 3.0  # [s] signal to exit: the 2 s design target, with slack for a loaded machine
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
WORD = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}
CRASH = re.compile("Fatal Python error|Traceback|Segmentation|core dumped|Exception ignored|Aborted")
REPEATS = int(os.environ.get("DRIVEOPT_EXIT_REPEATS", "60"))
PARALLEL = 3  # children at once in the slow tests

PLAN = ["plan", "--problem", "static-blockage", "--samples", "20", "--repeats", "40"]  # repeats: a run window longer than the
# largest delay a signal is sent after (0.2 s)
SHORT_EPISODE = ["--scenarios", "two-lane-d1.0", "--episodes", "1", "--samples", "16", "--iterations", "1",
                 "--duration", "0.3"]
COMMANDS = {
    "plan": lambda out: PLAN,
    "collect": lambda out: ["collect", *SHORT_EPISODE, "--out", str(out / "demos.h5")],
    "drive": lambda out: ["drive", "--scenario", "two-lane-d1.0", "--samples", "16", "--duration", "0.3",
                          "--video", "", "--json", str(out / "drive.json")],
    "bench-1": lambda out: ["bench", "--scenarios", "two-lane-d1.0", "--planners", "bilevel", "--samples", "16",
                            "--episodes", "1", "--duration", "0.3", "--workers", "1", "--out", str(out)],
    "bench-2": lambda out: ["bench", "--scenarios", "two-lane-d1.0", "--planners", "bilevel", "--samples", "16",
                            "--episodes", "2", "--duration", "0.3", "--workers", "2", "--out", str(out)],
}
# The compilation and the first plan happen in the workers for bench-2: its signals there are aimed by time instead.
WINDOWS = ("start", "compile", "run", "end")
WORKERS_BUSY_S = 6.0  # [s] after the handlers, bench-2's workers are starting or compiling (the `compile`/`run` windows)


class Run:
    """One child: the command, the window its signal is aimed at, how it ended."""

    def __init__(self, command: str, window: str, signum: int, out: Path, delay: float = 0.0):
        out.mkdir(parents=True, exist_ok=True)
        self.command, self.window, self.signum, self.delay = command, window, signum, delay
        # faulthandler: a crash shows where it happened (and its "Fatal Python error" is caught below)
        env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "EXIT_WINDOW_CHILD": window, "PYTHONFAULTHANDLER": "1",
               "DRIVEOPT_EXIT_PAUSE_S": str(END_PAUSE_S) if window == "end" else ""}
        if window == "compile":  # a planner loaded from the cache would never reach the compilation
            env["DRIVEOPT_COMPILATION_CACHE"] = "0"
        self.proc = subprocess.Popen([sys.executable, str(CHILD), *COMMANDS[command](out)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)
        self.stderr = ""
        self.signal_to_exit_s: float | None = None
        self.thread = threading.Thread(target=self._signal_in_window, daemon=True)
        self.thread.start()

    def _signal_in_window(self) -> None:
        stdout = threading.Thread(target=self.proc.stdout.read, daemon=True)  # a full pipe must not stall the child
        stdout.start()
        lines: list[str] = []
        if self.window == "start" or (self.command == "bench-2" and self.window != "end"):
            reached = _wait_for_handlers(self.proc)
            if reached and self.window != "start":
                time.sleep(WORKERS_BUSY_S if self.window == "compile" else 2 * WORKERS_BUSY_S)
        else:
            wanted = PAUSE_LINE if self.window == "end" else f"{MARK} {self.window}"
            reached = False
            for line in self.proc.stderr:
                lines.append(line)
                if wanted in line:
                    reached = True
                    break
        if reached and self.proc.poll() is None:
            time.sleep(self.delay)
            start = time.monotonic()
            self.proc.send_signal(self.signum)
            self.proc.wait()
            self.signal_to_exit_s = time.monotonic() - start
        self.stderr = "".join(lines) + self.proc.stderr.read()
        self.proc.wait()
        stdout.join()

    def finish(self, deadline: float) -> "Run":
        """Wait for the end until ``deadline`` (time.monotonic()), then kill the child (started here)."""
        self.thread.join(max(deadline - time.monotonic(), 0.0))
        if self.thread.is_alive():
            self.proc.kill()
            self.thread.join()
        return self

    def messages(self) -> list[str]:
        """stderr without the marks and progress bars: what the user reads once it has ended."""
        lines = [line.rpartition("\r")[2] for line in self.stderr.splitlines()]
        return [line for line in lines if line.strip() and MARK not in line and PAUSE_LINE not in line]

    def problem(self) -> str | None:
        """What is wrong with how it ended, or None."""
        if self.signal_to_exit_s is None:
            return f"ended ({self.proc.returncode}) before its window"
        if CRASH.search(self.stderr):
            return f"crash text (status {self.proc.returncode})"
        if self.proc.returncode != STATUS[self.signum]:
            return f"status {self.proc.returncode}"
        word = WORD[self.signum]
        if not (self.messages() and re.fullmatch(rf"driveopt: {word}(: .*)?", self.messages()[-1])):
            return "no line"
        if sum(line.startswith("driveopt: ") for line in self.messages()) != 1:
            return "more than one line"
        if self.signal_to_exit_s > EXIT_LIMIT_S:
            return f"slow exit ({self.signal_to_exit_s:.1f} s)"
        return None

    def report(self) -> str:
        return f"{self.command}/{self.window}/{signal.Signals(self.signum).name}: {self.problem()}\n{self.stderr[-3000:]}"


def _wait_for_handlers(proc: subprocess.Popen) -> bool:
    """Poll until SIGTERM is among the caught signals of ``proc`` (its handlers are installed); False if it ended."""
    bit = 1 << (signal.SIGTERM - 1)
    while proc.poll() is None:
        try:
            fields = dict(line.split(":", 1) for line in Path(f"/proc/{proc.pid}/status").read_text().splitlines()
                          if ":" in line)
        except OSError:
            return False
        if int(fields["SigCgt"], 16) & bit:
            return True
        time.sleep(0.001)
    return False


# ---- the default run: a few signals per window on the cheapest commands, all children at once ----

# The cheapest command in each window (both signals at the start, where the command ends while it imports; collect's
# start too, whose imports differ); the compilation window (a cold compile, the dearest case) is the default suite's in
# tests/cli/test_interrupts.py, and every command in every window is here under slow.
QUICK = [("plan", "start", signal.SIGINT), ("plan", "start", signal.SIGTERM), ("plan", "run", signal.SIGINT),
         ("plan", "end", signal.SIGTERM), ("collect", "start", signal.SIGTERM)]


@pytest.fixture(scope="module")
def quick_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("exit-windows")
    started = {case: Run(*case, root / f"{case[0]}-{case[1]}-{case[2]}", delay=0.3 if case[1] == "end" else 0.0)
               for case in QUICK}
    deadline = time.monotonic() + REACH_S
    return {case: run.finish(deadline) for case, run in started.items()}


@pytest.mark.parametrize("case", QUICK, ids=lambda c: f"{c[0]}-{c[1]}-{signal.Signals(c[2]).name}")
def test_a_signal_in_any_window_ends_the_command_with_its_status_and_one_line(quick_runs, case):
    run = quick_runs[case]
    assert run.problem() is None, run.report()


def test_a_command_that_finishes_exits_with_its_status_and_no_pause_line_by_default(tmp_path):
    env = {**os.environ, "DRIVEOPT_EXIT_PAUSE_S": ""}
    proc = subprocess.run([sys.executable, "-m", "driveopt.cli", "plan", "--problem", "no-such-problem"],
                          capture_output=True, text=True, timeout=120, env=env, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("driveopt: error: no problem named")
    assert len(proc.stderr.splitlines()) == 1


def test_each_warning_of_a_command_is_one_line():
    # three lanes: no CVAE weights are shipped for them, so the planner warns and plans from the Gaussian start
    proc = subprocess.run([sys.executable, "-m", "driveopt.cli", "plan", "--problem", "slow-leader-three-lane",
                           "--planner", "cvae", "--samples", "16", "--repeats", "0"],
                          capture_output=True, text=True, timeout=REACH_S, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stderr.splitlines() == [
        "driveopt: warning: no CVAE weights shipped for 3-lane roads: using the Gaussian start instead"]


def test_the_warning_format_is_the_programs_not_a_callers():
    import warnings

    from driveopt.cli import main

    plain = warnings.formatwarning
    assert main(["problems"]) == 0
    assert warnings.formatwarning is plain


# ---- the slow runs: REPEATS signals per window and command ----

@pytest.mark.slow
@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize("command", list(COMMANDS))
def test_repeated_signals_in_a_window_never_crash(tmp_path, command, window):
    signals = itertools.cycle((signal.SIGINT, signal.SIGTERM))
    cases = [(i, next(signals)) for i in range(REPEATS)]
    runs: list[Run] = []
    for batch_start in range(0, REPEATS, PARALLEL):
        batch = []
        for i, signum in cases[batch_start:batch_start + PARALLEL]:
            delay = (i % 8) / 8 * 0.8 * END_PAUSE_S if window == "end" else (i % 5) * 0.05
            batch.append(Run(command, window, signum, tmp_path / str(i), delay=delay))
        deadline = time.monotonic() + REACH_S
        runs += [run.finish(deadline) for run in batch]
    outcomes = Counter(run.problem() or f"ok {run.proc.returncode}" for run in runs)
    slowest = max((run.signal_to_exit_s for run in runs if run.signal_to_exit_s is not None), default=None)
    print(f"\n{command}/{window}: {len(runs)} signals: {dict(outcomes)}; longest signal to exit: "
          f"{slowest if slowest is None else round(slowest, 2)} s")
    failed = [run for run in runs if run.problem() is not None]
    assert not failed, "\n\n".join(run.report() for run in failed[:3])


# ---- the child: `EXIT_WINDOW_CHILD=WINDOW python test_exit_windows.py DRIVEOPT-ARGS...` ----


def _mark(what: str) -> None:
    print(f"{MARK} {what}", file=sys.stderr, flush=True)


def _mark_the_planner_compilation() -> None:
    """Mark the start of XLA's compilation of the planner (run as a child: ``planner_marks`` is this folder's)."""
    from planner_marks import on_planner_compilation

    on_planner_compilation(lambda: _mark("compile"))


def _mark_the_first_plan() -> None:
    """Mark the return of the first plan (:func:`driveopt.planner.plan`, imported by name by its callers later)."""
    import functools

    import driveopt.planner

    plan = driveopt.planner.plan
    calls = itertools.count()

    @functools.wraps(plan)
    def marked(*args, **kwargs):
        result = plan(*args, **kwargs)
        if next(calls) == 0:
            _mark("run")
        return result

    driveopt.planner.plan = marked


if __name__ == "__main__":
    window = os.environ.pop("EXIT_WINDOW_CHILD", "")
    if window == "compile":
        _mark_the_planner_compilation()
    elif window == "run":
        _mark_the_first_plan()
    from driveopt.cli import main

    sys.argv = ["driveopt", *sys.argv[1:]]
    main()  # the program: it ends the process
