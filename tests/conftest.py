import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
# JAX's persistent compilation cache, shared by the two xdist workers and the subprocesses that tests start
# (collect, bench): the same small planners compile once per run instead of once per process (-15% wall time
# on the subprocess-heavy files). Set before JAX is imported; subprocesses inherit it.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".pytest_cache", "jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from driveopt.config import PlannerConfig  # noqa: E402

# One small configuration shared by the tests, so that it compiles once per session.
SMALL = PlannerConfig().replace(
    sampler=dict(num_samples=250, num_iterations=4, num_constraint_elites=80, num_elites=30),
    projection=dict(max_iterations=20),
)


@pytest.fixture(scope="session")
def small_config() -> PlannerConfig:
    return SMALL


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
