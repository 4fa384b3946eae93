"""benchmarks/p2_closed_loop.py as a process with two tiny points of fake episodes, for the test that stops one.

    python tests/p2_sweep_child.py SWEEP-ARGS...   # as `python benchmarks/p2_closed_loop.py SWEEP-ARGS...`

Episodes are bench_child.py's (``BENCH_CHILD_FAST``, ``BENCH_CHILD_SLOW``, ``BENCH_CHILD_MARKS``): no simulator runs.
"""

import functools
import importlib.util
import sys
from pathlib import Path

from bench_child import slow_episode

SCRIPT_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "p2_closed_loop.py"


def main(argv: list[str]) -> int:
    spec = importlib.util.spec_from_file_location("p2_closed_loop", SCRIPT_PATH)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    tiny = [script.Point("two-lane-d1.0", "idm", 20, k, 8, "plain", k or 5) for k in (None, 2)]
    script.points = lambda figure, episodes=None, planners=None, scenarios=None, xs=None: tiny
    script.run_bench = functools.partial(script.run_bench, episode_fn=slow_episode)
    return script.main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
