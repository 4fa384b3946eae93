"""Run jobs in parallel and hand each result to one writer as it comes: in this process, local worker
processes, or a Ray cluster.

``episode_fn(job, options) -> dict`` must be a module-level function (it is pickled to the workers)
and derive every random choice from the job and the options. The parent process is the only one that
writes: ``finished(record)`` is called in it, once per job, in completion order.

Local workers are spawned processes bound to the parent: they never see Ctrl-C (the parent handles it),
end within a second when the parent ends however it ends (``kill -9`` included), and are killed at
once, not waited for, when :func:`execute` stops on an exception (Ctrl-C, SIGTERM, a failed episode):
the results of the episodes in flight would be dropped anyway. On Linux, when there are no
more workers than CPUs this process may use (its affinity: ``taskset`` limits it), each worker is bound to
its own share of them (:func:`cpu_shares`): XLA's thread pools of unbound workers contend for every core,
and two bound workers run about a fifth more closed-loop episodes per hour on two cores
(docs/results/speed.md, "Parallel workers"). Ray runs the same
function as Ray tasks on the cluster that ``RAY_ADDRESS`` names (a local instance when unset); on an
exception the unfinished tasks on a cluster are cancelled, and a local instance that :func:`execute` started
is killed with everything it runs, within a second. When this process is killed with ``kill -9`` instead,
Ray's own fate sharing ends the instance's GCS, raylet and workers with it, and a small reaper process started
with the instance kills the rest within a second (the raylet's two agents, which would linger for a minute).
Install Ray with ``pip install 'driveopt[ray]'``.

:func:`execute_cells` runs cells of jobs instead (``driveopt bench --lockstep``, :mod:`driveopt.experiments.lockstep`):
in this process one after another, in local worker processes, or one Ray task per cell, a GPU each where the cluster
has any.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import multiprocessing
import os
import platform
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from driveopt.errors import DriveoptError, UnknownNameError
from driveopt.experiments.store import JobKey

EpisodeFn = Callable[[JobKey, dict], dict]
CellFn = Callable[..., list]  # (jobs, options, finished or None, *args) -> records (driveopt.experiments.lockstep)
BACKENDS = ("local", "ray")
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
ORPHAN_POLL_S = 0.5  # [s] how often a worker checks that its parent is alive
RAY_POLL_S = 0.1  # [s] how long one wait for a Ray task lasts at most
MANAGER_JOIN_S = 0.5  # [s] what a stopped pool's manager thread gets to end (it sees its workers killed at once)
RAY_SHUTDOWN_S = 0.4  # [s] what a stopped command gives Ray's shutdown of its local instance before killing it


class BackendError(DriveoptError):
    """The chosen backend cannot run here (Ray not installed, no cluster at RAY_ADDRESS)."""


def call(episode_fn: EpisodeFn, job: JobKey, options: dict) -> dict[str, Any]:
    """``episode_fn``'s record with the job's key fields added."""
    return {**episode_fn(job, options), **job._asdict()}


def check_backend(backend: str) -> None:
    """UnknownNameError for an unknown backend, BackendError when it cannot run here (Ray not installed)."""
    if backend not in BACKENDS:
        raise UnknownNameError(f"unknown backend '{backend}'; valid: {', '.join(BACKENDS)}")
    if backend == "ray":
        _import_ray()


def execute(
    todo: Sequence[JobKey],
    options: dict,
    episode_fn: EpisodeFn,
    finished: Callable[[dict], None],
    *,
    workers: int = 1,
    backend: str = "local",
) -> None:
    """Run ``episode_fn(job, options)`` for every job and hand each record to ``finished`` as it comes.

    workers: local processes (spawn); 1 runs in this process. backend: 'local' or 'ray'.
    """
    check_backend(backend)
    if backend == "ray":
        _run_ray(todo, options, episode_fn, finished)
    elif workers == 1:
        for job in todo:
            finished(call(episode_fn, job, options))
    else:
        _run_pool(todo, options, episode_fn, finished, workers)


def usable_cpus() -> list[int]:
    """The CPUs this process may run on (its affinity; every CPU where the platform has no affinity)."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def cpu_model() -> str:
    """The processor's model name (Linux: /proc/cpuinfo's "model name"; elsewhere the platform's processor string;
    "unknown" when neither says): plan times are comparable only between records of one model."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def cpu_shares(cpus: Sequence[int], workers: int) -> list[tuple[int, ...]]:
    """``cpus`` split into ``workers`` contiguous shares whose sizes differ by at most one; none (``[]``: workers
    unbound) when there are more workers than CPUs."""
    cpus = sorted(cpus)
    if workers > len(cpus):
        return []
    size, extra = divmod(len(cpus), workers)
    bounds = [i * size + min(i, extra) for i in range(workers + 1)]
    return [tuple(cpus[bounds[i]:bounds[i + 1]]) for i in range(workers)]


def _run_pool(todo: Sequence[JobKey], options: dict, episode_fn: EpisodeFn, finished: Callable[[dict], None],
              workers: int) -> None:
    _run_pool_tasks(call, [(episode_fn, job, options) for job in todo], finished, workers)


def _run_pool_tasks(fn: Callable[..., Any], arguments: list[tuple], finished: Callable[[Any], None],
                    workers: int) -> None:
    """``fn(*args)`` for every item of ``arguments`` in ``workers`` local processes; each answer handed to
    ``finished`` as it comes."""
    # With the spawn context, submit() starts the workers in this thread, which outlives them: the
    # parent-death signal (sent when the creating thread ends) cannot fire while the pool is in use.
    context = multiprocessing.get_context("spawn")
    shares = context.SimpleQueue()
    for share in cpu_shares(usable_cpus(), workers) if hasattr(os, "sched_setaffinity") else []:
        shares.put(share)
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                  initializer=_bind_to_parent, initargs=(os.getpid(), shares))
    try:
        with _ctrl_c_held_from_workers():
            futures = [pool.submit(fn, *args) for args in arguments]
        for future in cf.as_completed(futures):
            finished(future.result())
    except BaseException:
        _kill_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True)


@contextlib.contextmanager
def _ctrl_c_held_from_workers():
    """Block SIGINT in this thread while it spawns workers: they start with it blocked (and ignore it once set up, see
    :func:`_bind_to_parent`), so a Ctrl-C sent to the whole process group never stops one halfway through its
    imports with a traceback. This process still gets it at once, on one of its other threads."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def _kill_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel the queued jobs and kill the workers now (what ``kill_workers`` does from Python 3.14), then give the
    pool's manager thread up to MANAGER_JOIN_S to end: one still running at interpreter exit races
    ``concurrent.futures``' exit hook, which can print a traceback (a closed wake-up pipe: "Bad file descriptor")."""
    manager = getattr(pool, "_executor_manager_thread", None)
    if hasattr(pool, "kill_workers"):
        pool.kill_workers()
    else:
        processes = list((pool._processes or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            with contextlib.suppress(ProcessLookupError, ValueError):  # already ended, or closed
                process.kill()
    if manager is not None:
        manager.join(MANAGER_JOIN_S)


def _bind_to_parent(parent: int, shares: Any) -> None:
    """Worker initializer: leave Ctrl-C to the parent, end this worker as soon as ``parent`` ends, and run on the next
    CPU share of the queue ``shares`` when it has one (before anything starts XLA's thread pools)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked while spawned: a pending one is dropped
    if not shares.empty():
        os.sched_setaffinity(0, shares.get())
    _set_parent_death_signal()
    threading.Thread(target=_exit_when_orphaned, args=(parent,), name="driveopt-parent-watch", daemon=True).start()


def _set_parent_death_signal() -> None:
    """On Linux, have the kernel SIGKILL this process when its parent ends (best effort elsewhere: none)."""
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):  # no libc or no prctl: the watch thread remains
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


def _exit_when_orphaned(parent: int) -> None:
    """Exit the process once ``parent`` is no longer its parent (also when it ended before the worker was set up)."""
    while os.getppid() == parent:
        time.sleep(ORPHAN_POLL_S)
    os._exit(1)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise BackendError("the ray backend needs Ray: pip install 'driveopt[ray]' (or use --backend local)") from None
    return ray


def _run_ray(todo: Sequence[JobKey], options: dict, episode_fn: EpisodeFn, finished: Callable[[dict], None]) -> None:
    _run_ray_tasks(call, [(episode_fn, job, options) for job in todo], finished)


def execute_cells(cells: Sequence[Sequence[JobKey]], options: dict, cell_fn: CellFn, finished: Callable[[dict], None],
                  *, args: tuple = (), backend: str = "local", workers: int = 1, gpus: float | None = None) -> None:
    """Run ``cell_fn(cell, options, None, *args)`` (a module-level function returning the cell's records) for every
    cell of jobs and hand each record to ``finished``: in this process one cell after another (``workers`` 1:
    ``cell_fn`` then gets ``finished`` in place of None and hands each record over as its episode ends), in
    ``workers`` local processes (bound to their share of the CPUs, as :func:`execute`'s), or as Ray tasks; from a
    process or a task, a cell's records are handed over when it ends (a stopped run keeps the records of the cells
    that ended). ``gpus``: the GPUs a Ray task asks for (None: 1 when the cluster has any, so that each cell has a
    GPU to itself; else 0)."""
    check_backend(backend)
    if backend != "ray" and workers == 1:
        for cell in cells:
            cell_fn(cell, options, finished, *args)
        return

    def each(records: list[dict]) -> None:
        for record in records:
            finished(record)

    arguments = [(cell, options, None, *args) for cell in cells]
    if backend == "ray":
        _run_ray_tasks(cell_fn, arguments, each, gpus=gpus)
    else:
        _run_pool_tasks(cell_fn, arguments, each, workers)


def _run_ray_tasks(fn: Callable[..., Any], arguments: list[tuple], finished: Callable[[Any], None], *,
                   gpus: float | None = 0) -> None:
    """``fn(*args)`` as one Ray task per item of ``arguments``; each answer handed to ``finished`` as it comes.
    ``gpus``: per task (None: 1 when the cluster has any GPU, else 0)."""
    global _local_ray
    ray = _import_ray()
    if not ray.is_initialized():
        _local_ray = _start_ray(ray)
    if gpus is None:
        gpus = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
    remote = ray.remote(num_gpus=gpus)(fn) if gpus else ray.remote(fn)
    refs = [remote.remote(*args) for args in arguments]
    try:
        while refs:  # in short waits: Ray notices a signal in a blocking wait only about once a second
            done, refs = ray.wait(refs, num_returns=1, timeout=RAY_POLL_S)
            for ref in done:
                finished(ray.get(ref))
    except BaseException:
        if _local_ray is not None:  # nothing outlives this process: the instance goes, and its tasks with it
            _local_ray.stop(ray)
            _local_ray = None
        else:  # a cluster that stays up: stop this command's tasks on it
            for ref in refs:
                ray.cancel(ref, force=True)
        raise


# The reaper: kills the processes named by its arguments once its stdin ends, that is when the process holding the
# other end ends, however it ends. psutil remembers when each process started, so a pid reused meanwhile is spared.
REAPER = """
import sys, psutil
processes = []
for pid in sys.argv[1:]:
    try:
        processes.append(psutil.Process(int(pid)))
    except psutil.Error:
        pass
sys.stdin.buffer.read()
for process in processes:
    try:
        process.kill()
    except psutil.Error:
        pass
"""


class _LocalRay:
    """A local Ray instance this process started: its processes (``psutil.Process``, children of this one), and a
    reaper that kills them, and what they started, when this process ends first (``kill -9`` included). Ray's own
    fate sharing ends the GCS, the raylet and the workers with this process, but not the raylet's agents, which
    linger for a minute."""

    def __init__(self, processes: list[Any]):
        import subprocess

        self.processes = processes
        # in its own session, so that a Ctrl-C to this process's group passes it by
        self.reaper = subprocess.Popen([sys.executable, "-c", REAPER, *(str(p.pid) for p in _with_descendants(processes))],
                                       stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, start_new_session=True)

    def stop(self, ray: Any) -> None:
        """End the instance within about a second: Ray's own shutdown gets RAY_SHUTDOWN_S (it disconnects this driver
        in a fraction of that, then stops the processes one by one, gracefully, which takes longer), then every
        process of the instance is killed, those it started included."""
        import psutil  # a dependency of Ray's

        doomed = _with_descendants(self.processes)
        stopper = threading.Thread(target=ray.shutdown, name="driveopt-ray-shutdown", daemon=True)
        stopper.start()
        stopper.join(RAY_SHUTDOWN_S)
        for process in doomed:
            with contextlib.suppress(psutil.Error):  # already ended (psutil also refuses a reused pid)
                process.kill()
        self.reaper.stdin.close()  # nothing left for it to do
        stopper.join(RAY_SHUTDOWN_S)


_local_ray: _LocalRay | None = None  # the local Ray instance this process started, while it runs


def _start_ray(ray: Any) -> _LocalRay | None:
    """Connect to the cluster at ``RAY_ADDRESS`` (or one already running here), or start a local instance: returned."""
    import psutil  # a dependency of Ray's

    before = {child.pid for child in psutil.Process().children()}
    with _sigterm_kept():
        ray.init(address=os.environ.get("RAY_ADDRESS"), ignore_reinit_error=True, log_to_driver=False)
    started = [child for child in psutil.Process().children() if child.pid not in before]
    return _LocalRay(started) if started else None


def _with_descendants(roots: list[Any]) -> list[Any]:
    """``roots`` (``psutil.Process``) and every process they started that still runs."""
    import psutil

    found = []
    for root in roots:
        with contextlib.suppress(psutil.Error):  # ended meanwhile
            found += [root, *root.children(recursive=True)]
    return found


@contextlib.contextmanager
def _sigterm_kept():
    """Give SIGTERM back to this process's handler after the block: Ray's driver installs its C++ crash handler for it
    too, which prints a stack dump of this process before passing the signal on."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = signal.getsignal(signal.SIGTERM)
    try:
        yield
    finally:
        if handler is not None:  # None: set outside Python, nothing to give back
            signal.signal(signal.SIGTERM, handler)


COMPILE_NOTICE_SECONDS = 1.0  # [s] an episode whose planner compiled for longer than this says so (a cached one loads faster)


def compile_ahead(bar, planners: list[str]) -> None:
    """One line above the progress ``bar`` before the episodes start (none when the bar is off or nothing runs): each
    worker's first episode of each of ``planners`` compiles it, unless the compilation cache holds it, and the bar
    stands still meanwhile."""
    if planners and not getattr(bar, "disable", False):
        bar.write(f"driveopt: each worker's first episode of {', '.join(planners)} compiles it unless the compilation "
                  "cache holds it (tens of seconds; the bar waits meanwhile) ...", file=sys.stderr)


def compile_notice(bar, planner: str, seconds: float) -> None:
    """One line above the progress ``bar`` (on its stream; none when the bar is off) when an episode's ``planner`` compiled
    for ``seconds`` [s] (a worker's first episode of a planner, unless the compilation cache held it): the time the bar
    stood still."""
    if seconds > COMPILE_NOTICE_SECONDS and not getattr(bar, "disable", False):
        bar.write(f"driveopt: {planner} compiled in {seconds:.1f} s (once per worker and planner; the compilation "
                  "cache keeps it for later runs)", file=sys.stderr)
