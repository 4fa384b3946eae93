import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
# JAX's persistent compilation cache stays off: with jaxlib 0.10.2 an xdist worker crashed (SIGSEGV) inside the
# cache's executable serialisation, which hangs the whole run, and the cache saved under 10% of the suite's time.

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
