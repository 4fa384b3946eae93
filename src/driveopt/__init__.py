"""driveopt: bi-level sampling + batch-projection motion planning for dense highway traffic (JAX).

    from driveopt import PlannerConfig, build_problem, load_scene, plan
    scene = load_scene("static-blockage")
    result = plan(build_problem(scene), PlannerConfig(), key=jax.random.PRNGKey(0), x_offset=scene.ego.x)

``import driveopt`` registers the gymnasium ids ``driveopt/highway-v0``, ``driveopt/two-way-v0``, ``driveopt/merge-v0``,
``driveopt/driving-v0`` and ``driveopt/controlled-v0`` without importing gymnasium (:mod:`driveopt.gym_envs`).

Where things live: the inputs (``config``, ``scene``, ``prediction``, ``problem``), the numerics (``basis``, ``qp``,
``projection``, ``costs``, ``sampler``), the planner's strategies (``ranking``, ``fallback``, ``row_sharing``, and
``method``: the three as one value), ``planner`` (``solve`` and ``plan``), the learned components (``learned/``,
``priors/``, ``safety/``; one row each in ``learned_kinds``), ``sim/`` (highway-env), ``drivers/`` and ``registry`` (who
drives), ``training/``, ``experiments/``, ``controller`` (:class:`Controller`: a planner driving the user's own
highway-env env; ``sb3``: it as a Stable-Baselines3 policy and gymnasium env), ``viz/`` and ``cli/``. The layer order, each part importing only parts of earlier layers, is written
once, in :data:`driveopt.layers.LAYERS`.
"""

from driveopt.lazy import lazy_exports

# Public name -> the module that defines it. Imported on first use (``driveopt.plan``, ``from driveopt import plan``),
# so that ``import driveopt`` and the command line's help and listings load neither JAX nor highway-env.
# A new export is one line here.
_EXPORTS = {
    "ConfigError": "driveopt.checks",
    "BasisConfig": "driveopt.config", "CostConfig": "driveopt.config", "PlannerConfig": "driveopt.config",
    "ProjectionConfig": "driveopt.config", "QPConfig": "driveopt.config", "SamplerConfig": "driveopt.config",
    "DriveoptError": "driveopt.errors",
    "Fallback": "driveopt.fallback",
    "DRIVEOPT_METHOD": "driveopt.method", "Method": "driveopt.method", "papers_method": "driveopt.method",
    "PlanResult": "driveopt.planner", "PlanStatus": "driveopt.planner", "Solution": "driveopt.planner",
    "plan": "driveopt.planner", "solve": "driveopt.planner",
    "GaussianPrior": "driveopt.priors", "Prior": "driveopt.priors", "Proposal": "driveopt.priors",
    "PlanningProblem": "driveopt.problem", "build_problem": "driveopt.problem",
    "CostPlusResidual": "driveopt.ranking", "FeasibilityFirst": "driveopt.ranking", "P1AuthorsRanking": "driveopt.ranking",
    "DistinctRows": "driveopt.row_sharing", "EveryRow": "driveopt.row_sharing",
    "EgoState": "driveopt.scene", "Neighbour": "driveopt.scene", "ProblemError": "driveopt.scene", "Road": "driveopt.scene",
    "Scene": "driveopt.scene", "load_scene": "driveopt.scene",
    "Controller": "driveopt.controller", "RenderPlans": "driveopt.controller", "gym_make": "driveopt.sim.rewards",
    "ControllerEnv": "driveopt.sb3", "ControllerPolicy": "driveopt.sb3", "NULL_POLICY": "driveopt.sb3",
}
__all__ = list(_EXPORTS)


__getattr__, __dir__ = lazy_exports("driveopt", _EXPORTS, globals())


__version__ = "0.1.0"

from driveopt import gym_envs as _gym_envs  # noqa: E402  light: registers the gymnasium ids once gymnasium is imported

_gym_envs.install()
