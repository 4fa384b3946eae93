"""driveopt: bi-level sampling + batch-projection motion planning for dense highway traffic (JAX).

    from driveopt import PlannerConfig, build_problem, load_scene, plan
    scene = load_scene("static-blockage")
    result = plan(build_problem(scene), PlannerConfig(), key=jax.random.PRNGKey(0), x_offset=scene.ego.x)

Where things live, in layers (each imports only those before it): ``errors``, ``checks`` and ``config``;
``scene`` (the world), ``prediction`` (neighbours' motion), ``observation`` (the learned components'
features), ``problem`` (arrays for the planner); the numerics ``basis``, ``qp``, ``xla``, ``trajectory``,
``projection``, ``costs``, ``sampler`` (the Prior contract and the Gaussian prior); the strategies
``ranking``, ``fallback``, ``batch_rows``; ``filtering`` (the SafetyFilter contract); ``planner`` (``solve``
and ``plan``); ``files``; ``learned/`` (networks), ``priors/``, ``safety/``, ``data/`` (demonstrations),
``sim/`` (highway-env), ``rl/``, ``drivers/`` and ``registry`` (who drives); ``training/``;
``experiments/`` (rollout, bench, collect); ``viz/``, ``cli/``.
"""

from driveopt.checks import ConfigError
from driveopt.batch_rows import SamplesOnly, StopRows
from driveopt.config import BasisConfig, CostConfig, PlannerConfig, ProjectionConfig, QPConfig, SamplerConfig
from driveopt.errors import DriveoptError
from driveopt.fallback import Fallback
from driveopt.planner import PlanResult, PlanStatus, Solution, plan, solve
from driveopt.priors import GaussianPrior, Prior, Proposal
from driveopt.problem import PlanningProblem, build_problem
from driveopt.ranking import CostPlusResidual, FeasibilityFirst
from driveopt.scene import EgoState, Neighbour, ProblemError, Road, Scene, load_scene

__all__ = [
    "BasisConfig", "ConfigError", "CostConfig", "PlannerConfig", "ProjectionConfig", "QPConfig", "SamplerConfig",
    "DriveoptError", "PlanResult", "PlanStatus", "Solution", "plan", "solve", "GaussianPrior", "Prior", "Proposal",
    "PlanningProblem", "build_problem", "EgoState", "Neighbour", "ProblemError", "Road", "Scene", "load_scene",
    "CostPlusResidual", "FeasibilityFirst", "Fallback", "SamplesOnly", "StopRows",
]
__version__ = "0.1.0"
