"""Run jobs in parallel and hand each result to one writer as it comes: in this process, local worker
processes, or a Ray cluster.

``episode_fn(job, options) -> dict`` must be a module-level function (it is pickled to the workers)
and derive every random choice from the job and the options. The parent process is the only one that
writes: ``finished(record)`` is called in it, once per job, in completion order.

Local workers are spawned processes. Ray runs the same function as Ray tasks on the cluster that
``RAY_ADDRESS`` names (a local instance when unset); install it with ``pip install 'driveopt[ray]'``.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
from typing import Any, Callable, Sequence

from driveopt.errors import DriveoptError, UnknownNameError
from driveopt.experiments.store import JobKey

EpisodeFn = Callable[[JobKey, dict], dict]
BACKENDS = ("local", "ray")


class BackendError(DriveoptError):
    """The chosen backend cannot run here (Ray not installed, no cluster at RAY_ADDRESS)."""


def call(episode_fn: EpisodeFn, job: JobKey, options: dict) -> dict[str, Any]:
    """``episode_fn``'s record with the job's key fields added."""
    return {**episode_fn(job, options), **job._asdict()}


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
    if backend not in BACKENDS:
        raise UnknownNameError(f"unknown backend '{backend}'; valid: {', '.join(BACKENDS)}")
    if backend == "ray":
        _run_ray(todo, options, episode_fn, finished)
    elif workers == 1:
        for job in todo:
            finished(call(episode_fn, job, options))
    else:
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = [pool.submit(call, episode_fn, job, options) for job in todo]
            try:
                for future in cf.as_completed(futures):
                    finished(future.result())
            except BaseException:
                for future in futures:
                    future.cancel()
                raise


def _run_ray(todo: Sequence[JobKey], options: dict, episode_fn: EpisodeFn, finished: Callable[[dict], None]) -> None:
    try:
        import ray
    except ImportError:
        raise BackendError("the ray backend needs Ray: pip install 'driveopt[ray]' (or use --backend local)") from None
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
