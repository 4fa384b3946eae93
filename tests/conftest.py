import gc
import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
# JAX's persistent compilation cache stays off: it saved under 10% of the suite's time (CI starts from a clean clone).

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from driveopt.config import PlannerConfig

# One small configuration shared by the tests, so that it compiles once per session.
SMALL = PlannerConfig().replace(
    sampler=dict(num_samples=250, num_iterations=4, num_constraint_elites=80, num_elites=30),
    projection=dict(max_iterations=20),
)


@pytest.fixture(scope="session")
def small_config() -> PlannerConfig:
    return SMALL


def mapped_regions() -> int:
    """Memory mappings of this process (Linux; 0 where /proc is missing)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


def map_limit() -> int:
    try:
        with open("/proc/sys/vm/max_map_count") as limit:
            return int(limit.read())
    except (OSError, ValueError):
        return 65530  # Linux's default


@pytest.fixture(autouse=True)
def release_compiled_code_before_the_map_limit():
    """jaxlib >= 0.10 JITs every fused kernel of a CPU executable into its own three memory mappings (~1200 for one
    planner), and JAX keeps every executable it compiled. An xdist worker reached ~60000 mappings by the end of the
    suite; at Linux's limit (vm.max_map_count, 65530 by default) the next compile's mmap fails and the worker
    segfaults, which hangs the run. Past half the limit, the compiled code is dropped (later tests recompile)."""
    yield
    if mapped_regions() > map_limit() // 2:
        jax.clear_caches()
        gc.collect()


def reset_env(scenario, seed: int, **make_kwargs):
    """A driveopt env (:func:`driveopt.sim.env.make_env`) of ``scenario`` (a Scenario or a registered name), reset
    with ``seed``."""
    from driveopt.sim.env import make_env
    from driveopt.sim.scenarios import get_scenario

    env = make_env(get_scenario(scenario) if isinstance(scenario, str) else scenario, **make_kwargs)
    env.reset(seed=seed)
    return env


def box_corners(x: float, y: float, heading: float, length: float, width: float) -> np.ndarray:
    """(4, 2) corners of an oriented rectangle centred at (x, y)."""
    c, s = np.cos(heading), np.sin(heading)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return np.array([x, y]) + half @ np.array([[c, s], [-s, c]])


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals given by their corners."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True
