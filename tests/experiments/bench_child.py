"""A ``driveopt bench`` process with fake episodes, for the tests that interrupt or kill one.

    python tests/bench_child.py BENCH-ARGS...   # as `driveopt bench BENCH-ARGS...`

Episodes with ``episode < BENCH_CHILD_FAST`` take 0.1 s, the others ``BENCH_CHILD_SLOW`` seconds
(0: all fast). When ``BENCH_CHILD_MARKS`` names a folder, each worker writes an empty file named by
its pid there as an episode starts. No simulator runs, so the workers are cheap.
"""

import os
import sys
import time
from pathlib import Path


def slow_episode(job, options):
    marks = os.environ.get("BENCH_CHILD_MARKS")
    if marks:
        (Path(marks) / str(os.getpid())).touch()
    fast = job.episode < int(os.environ.get("BENCH_CHILD_FAST", "0"))
    time.sleep(0.1 if fast else float(os.environ.get("BENCH_CHILD_SLOW", "0")))
    return {"collided": False, "off_road": False, "mean_speed": 10.0, "plan_ms": [1.0], "sim_seconds": 0.1,
            "plan_seconds": 0.1, "steps": 1}


def main(argv: list[str]) -> int:
    import functools

    from driveopt.cli import main as cli_main
    from driveopt.experiments import bench

    bench.run_bench = functools.partial(bench.run_bench, episode_fn=slow_episode)
    return cli_main(["bench", *argv])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
