"""Run jobs in parallel and hand each result to one writer as it comes: in this process, local worker
processes, or a Ray cluster.

``episode_fn(job, options) -> dict`` must be a module-level function (it is pickled to the workers)
and derive every random choice from the job and the options. The parent process is the only one that
writes: ``finished(record)`` is called in it, once per job, in completion order.

Local workers are spawned processes bound to the parent: they ignore Ctrl-C (the parent handles it),
end within a second when the parent ends however it ends (``kill -9`` included), and are killed at
once, not waited for, when :func:`execute` stops on an exception (Ctrl-C, SIGTERM's SystemExit, a
failed episode): the results of the episodes in flight would be dropped anyway. On Linux, when there are no
more workers than CPUs this process may use (its affinity: ``taskset`` limits it), each worker is bound to
its own share of them (:func:`cpu_shares`): XLA's thread pools of unbound workers contend for every core,
and two bound workers run about a fifth more closed-loop episodes per hour on two cores (README). Ray runs the same
function as Ray tasks on the cluster that ``RAY_ADDRESS`` names (a local instance when unset), and
the unfinished tasks are cancelled on an exception; install it with ``pip install 'driveopt[ray]'``.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from driveopt.errors import DriveoptError, UnknownNameError
from driveopt.experiments.store import JobKey

EpisodeFn = Callable[[JobKey, dict], dict]
BACKENDS = ("local", "ray")
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
ORPHAN_POLL_S = 0.5  # [s] how often a worker checks that its parent is alive


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
    # With the spawn context, submit() starts the workers in this thread, which outlives them: the
    # parent-death signal (sent when the creating thread ends) cannot fire while the pool is in use.
    context = multiprocessing.get_context("spawn")
    shares = context.SimpleQueue()
    for share in cpu_shares(usable_cpus(), workers) if hasattr(os, "sched_setaffinity") else []:
        shares.put(share)
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                  initializer=_bind_to_parent, initargs=(os.getpid(), shares))
    try:
        futures = [pool.submit(call, episode_fn, job, options) for job in todo]
        for future in cf.as_completed(futures):
            finished(future.result())
    except BaseException:
        _kill_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True)


def _kill_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel the queued jobs and kill the workers now (what ``kill_workers`` does from Python 3.14)."""
    if hasattr(pool, "kill_workers"):
        pool.kill_workers()
        return
    processes = list((pool._processes or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(ProcessLookupError, ValueError):  # already ended, or closed
            process.kill()


def _bind_to_parent(parent: int, shares: Any) -> None:
    """Worker initializer: leave Ctrl-C to the parent, end this worker as soon as ``parent`` ends, and run on the next
    CPU share of the queue ``shares`` when it has one (before anything starts XLA's thread pools)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
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
    ray = _import_ray()
    if not ray.is_initialized():
        ray.init(address=os.environ.get("RAY_ADDRESS"), ignore_reinit_error=True, log_to_driver=False)
    remote = ray.remote(call)
    refs = [remote.remote(episode_fn, job, options) for job in todo]
    try:
        while refs:
            done, refs = ray.wait(refs, num_returns=1)
            finished(ray.get(done[0]))
    except BaseException:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise
