"""driveopt: bi-level sampling + batch-projection motion planning for dense highway traffic (JAX).

    from driveopt import PlannerConfig, build_problem, load_scene, plan
    scene = load_scene("static-blockage")
    result = plan(build_problem(scene), PlannerConfig(), key=jax.random.PRNGKey(0), x_offset=scene.ego.x)
"""

from driveopt.config import (
    BasisConfig,
    ConfigError,
    CostConfig,
    PlannerConfig,
    ProjectionConfig,
    QPConfig,
    SamplerConfig,
)
from driveopt.planner import PlanResult, PlanStatus, plan
from driveopt.problem import (
    EgoState,
    Neighbour,
    PlanningProblem,
    ProblemError,
    Road,
    Scene,
    build_problem,
    load_scene,
)
from driveopt.sampler import GaussianPrior, Proposal

__all__ = [
    "BasisConfig", "ConfigError", "CostConfig", "PlannerConfig", "ProjectionConfig", "QPConfig", "SamplerConfig",
    "PlanResult", "PlanStatus", "plan", "EgoState", "Neighbour", "PlanningProblem", "ProblemError", "Road", "Scene",
    "build_problem", "load_scene", "GaussianPrior", "Proposal",
]
__version__ = "0.1.0"
