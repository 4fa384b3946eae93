"""driveopt: bi-level sampling + batch-projection motion planning for dense highway traffic (JAX).

    from driveopt import PlannerConfig, build_problem, load_scene, plan
    scene = load_scene("static-blockage")
    result = plan(build_problem(scene), PlannerConfig(), key=jax.random.PRNGKey(0), x_offset=scene.ego.x)

Where things live: ``scene`` (the world), ``prediction`` (neighbours' motion), ``observation`` (the
learned components' features), ``problem`` (arrays for the planner); the numerics ``basis``, ``qp``,
``projection``, ``costs``, ``sampler``; ``planner`` (``solve`` and ``plan``); ``priors/``,
``safety/``, ``drivers/`` and ``registry`` (who proposes, filters and drives); ``sim/`` (highway-env),
``experiments/`` (bench), ``data/`` and ``learned/`` (demonstrations, networks, training),
``viz/``, ``cli/``; ``errors`` (the base error).
"""

from driveopt.checks import ConfigError
from driveopt.config import BasisConfig, CostConfig, PlannerConfig, ProjectionConfig, QPConfig, SamplerConfig
from driveopt.errors import DriveoptError
from driveopt.planner import PlanResult, PlanStatus, Solution, plan, solve
from driveopt.priors import GaussianPrior, Prior, Proposal
from driveopt.problem import PlanningProblem, build_problem
from driveopt.scene import EgoState, Neighbour, ProblemError, Road, Scene, load_scene

__all__ = [
    "BasisConfig", "ConfigError", "CostConfig", "PlannerConfig", "ProjectionConfig", "QPConfig", "SamplerConfig",
    "DriveoptError", "PlanResult", "PlanStatus", "Solution", "plan", "solve", "GaussianPrior", "Prior", "Proposal",
    "PlanningProblem", "build_problem", "EgoState", "Neighbour", "ProblemError", "Road", "Scene", "load_scene",
]
__version__ = "0.1.0"
