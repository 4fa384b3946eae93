"""The controller in Stable-Baselines3's and gymnasium's terms: a policy to evaluate, an env to vectorise.

SB3 evaluates a model with ``evaluate_policy(model, env)``: it calls ``model.predict(observation, state,
episode_start, deterministic)`` and steps a ``VecEnv`` with the actions. A driveopt planner does not act from the
observation array: it reads the simulator itself (the road, the neighbours, the car's limits, ``env.unwrapped``).
Two routes follow from that:

- :class:`ControllerPolicy` (in-process): ``predict`` bound to one env object, which it reads and plans for::

      env = Monitor(gymnasium.make("highway-v0", config={"action": {"type": "ContinuousAction"}, "duration": 10}))
      policy = ControllerPolicy(driveopt.Controller("bilevel", samples=100), env)
      mean_reward, std_reward = evaluate_policy(policy, env, n_eval_episodes=5)

  It works with the env itself or a ``DummyVecEnv`` of one env (same process, so the env the policy reads is the
  one SB3 steps). It cannot work with ``SubprocVecEnv``: there each env lives in a worker process and only
  observation arrays cross back, so there is nothing here to plan from. That is what :class:`ControllerEnv` is for.
- :class:`ControllerEnv` (any VecEnv): a gymnasium env whose ``step`` ignores its action (``Discrete(1)``) and
  drives one policy period with the controller inside the env, so the planning happens wherever the env lives
  (a ``SubprocVecEnv`` worker). Registered as ``driveopt/controlled-v0``; evaluate it with :data:`NULL_POLICY`::

      vec = make_vec_env("driveopt:driveopt/controlled-v0", n_envs=2, vec_env_cls=SubprocVecEnv,
                         env_kwargs={"env": "highway-v0", "config": {"duration": 10}, "planner": "bilevel", "samples": 100})
      mean_reward, std_reward = evaluate_policy(NULL_POLICY, vec, n_eval_episodes=4)

  (``"driveopt:..."`` makes gymnasium import driveopt in the worker first, which registers the id.)

Rewards, terminations and observations are the wrapped env's own. Neither class imports Stable-Baselines3.
"""

from __future__ import annotations

import itertools
import os
from typing import Any, Mapping

import gymnasium
import numpy as np

from driveopt.controller import Controller, ControllerError

DEFAULT_ENV = "highway-v0"  # what ControllerEnv drives when given no env
CONTINUOUS = {"type": "ContinuousAction"}


def _check_continuous(env: Any) -> None:
    """ControllerError unless ``env`` takes highway-env's ContinuousAction (acceleration, steering), the controller's."""
    space = getattr(env, "action_space", None)
    if not (isinstance(space, gymnasium.spaces.Box) and space.shape == (2,)):
        raise ControllerError(f"the env's action space is {space}, not ContinuousAction's Box(-1, 1, (2,)): make it with "
                              "config={'action': {'type': 'ContinuousAction'}}")


class ControllerPolicy:
    """``predict`` as SB3's models have it, driving the one env it is bound to with ``controller``.

    ``env``: a highway-env env with ContinuousAction (wrappers such as ``Monitor`` are fine), or a ``DummyVecEnv``
    of one such env; it is the env ``predict`` reads the state of, so it must be the env being stepped (SB3's
    ``evaluate_policy(policy, env)`` wraps a plain env in a ``DummyVecEnv`` of that same object). The observation
    is not read, only its shape: a batch of one (from a VecEnv) gets a (1, 2) action, a single observation a (2,)
    one. A new episode (``env.reset``, also the VecEnv's automatic one) is noticed and ``controller.reset(env,
    seed)`` called, with seeds ``seed``, ``seed + 1``, ... in episode order. Not for ``SubprocVecEnv`` (see the
    module docstring: use :class:`ControllerEnv`)."""

    def __init__(self, controller: Controller, env: Any, seed: int = 0) -> None:
        if not isinstance(controller, Controller):
            raise ControllerError(f"ControllerPolicy needs a driveopt.Controller, got {type(controller).__name__}")
        envs = getattr(env, "envs", None)  # a DummyVecEnv: its envs are here, in this process
        if envs is None and hasattr(env, "num_envs") and not isinstance(env, gymnasium.Env):
            raise ControllerError(f"ControllerPolicy reads the env it drives, and {type(env).__name__} keeps its envs in "
                                  "other processes: use driveopt.sb3.ControllerEnv (driveopt/controlled-v0) with NULL_POLICY")
        if envs is not None:
            if len(envs) != 1:
                raise ControllerError(f"ControllerPolicy drives one env, the VecEnv has {len(envs)}: make one policy per env "
                                      "or use driveopt.sb3.ControllerEnv")
            env = envs[0]
        if not hasattr(getattr(env, "unwrapped", None), "road"):
            raise ControllerError(f"ControllerPolicy needs a highway-env env, got {type(env.unwrapped).__name__}")
        _check_continuous(env)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ControllerError(f"seed must be a non-negative integer, got {seed!r}")
        self.controller, self.env = controller, env
        self._seeds = itertools.count(seed)
        self.observation_space, self.action_space = env.observation_space, env.action_space

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """(action, state): the controller's action for the bound env's current state ((1, 2) for a batch of one
        observation, (2,) for one observation), and ``state`` unchanged. ``deterministic`` is accepted for SB3's
        call; the plan depends on the per-episode seed."""
        batched = _batch_size(observation, self.observation_space)
        if batched is not None and batched != 1:
            raise ControllerError(f"ControllerPolicy drives one env, got a batch of {batched} observations: use "
                                  "driveopt.sb3.ControllerEnv for several envs")
        episode = self.controller.episode
        if episode is None or not episode.matches(self.env):  # a new episode: bind the controller to it
            self.controller.reset(self.env, seed=next(self._seeds))
        action = self.controller.act(self.env)
        return (action[None] if batched is not None else action), state


def _batch_size(observation: Any, space: Any) -> int | None:
    """Observations in ``observation``: None when it is one observation of ``space``, else the batch's length."""
    if isinstance(observation, Mapping):
        observation = next(iter(observation.values()))
        space = next(iter(space.spaces.values())) if isinstance(space, gymnasium.spaces.Dict) else None
    shape = np.shape(observation)
    if space is not None and getattr(space, "shape", None) is not None and shape == tuple(space.shape):
        return None
    return int(shape[0]) if shape else None


class ControllerEnv(gymnasium.Env):
    """A highway-env env driven by a driveopt controller: ``step(action)`` ignores ``action`` and steps the env with
    the controller's action for its current state; ``reset`` resets the env and the controller (seed: the one given,
    else 0, 1, 2, ... in episode order). Observations, rewards, terminations and infos are the env's own (``.env``),
    with ``info["driveopt"]``: the action taken and the planning status's name (or None); the planning time is
    ``controller.last.plan_seconds`` (not in ``info``: a step's info is the same for the same seed and action).

    ``env``: a gymnasium id (default ``highway-v0``; made with :func:`driveopt.gym_make`, ContinuousAction unless
    ``config`` gives an action, ``render_mode`` passed on) or an env object; ``controller``: a
    :class:`~driveopt.controller.Controller`, else one made from ``controller_kwargs`` (``planner``, ``samples``,
    ``v_des``, ``verbose``, ...). The action space is ``Discrete(1)``: there is nothing to choose, and an agent's
    action could not be told from an ignored one. Picklable by construction from an id (``SubprocVecEnv``)."""

    metadata = {"render_modes": ["human", "rgb_array"]}  # highway-env's

    def __init__(self, env: str | gymnasium.Env = DEFAULT_ENV, controller: Controller | None = None, *,
                 config: Mapping[str, Any] | None = None, render_mode: str | None = None, **controller_kwargs: Any) -> None:
        if isinstance(env, str):
            if config is not None and not isinstance(config, Mapping):
                raise ControllerError(f"config must be a mapping of highway-env settings, got {type(config).__name__}")
            if render_mode == "rgb_array":
                os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
            from driveopt.sim.rewards import gym_make

            try:
                env = gym_make(env, config={"action": dict(CONTINUOUS), **dict(config or {})}, render_mode=render_mode)
            except gymnasium.error.Error as exc:
                raise ControllerError(f"cannot make env {env!r}: {str(exc).splitlines()[0]}") from None
        elif config is not None or render_mode is not None:
            raise ControllerError("config and render_mode are for an env made by id; an env object comes made")
        if not isinstance(env, gymnasium.Env):
            raise ControllerError(f"env must be a gymnasium id or env, got {type(env).__name__}")
        if controller is None:
            controller = Controller(**controller_kwargs)
        elif controller_kwargs:
            raise ControllerError(f"give either a controller or its settings, not both ({', '.join(controller_kwargs)})")
        if not isinstance(controller, Controller):
            raise ControllerError(f"controller must be a driveopt.Controller, got {type(controller).__name__}")
        _check_continuous(env)
        self.env, self.controller = env, controller
        self.observation_space = env.observation_space
        self.action_space = gymnasium.spaces.Discrete(1)
        self.render_mode = env.render_mode
        self._episodes = itertools.count()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        observation, info = self.env.reset(seed=seed, options=options)
        episode = next(self._episodes)
        self.controller.reset(self.env, seed=episode if seed is None else int(seed))
        return observation, info

    def step(self, action: Any = 0) -> tuple[Any, float, bool, bool, dict]:
        if self.controller.episode is None:
            raise ControllerError("call reset() before step()")
        driven = self.controller.act(self.env)
        observation, reward, terminated, truncated, info = self.env.step(driven)
        status = self.controller.status
        info = {**info, "driveopt": {"action": driven.tolist(), "status": None if status is None else status.name}}
        return observation, reward, terminated, truncated, info

    def render(self) -> Any:
        """The controller's drawing (plans and HUD, :meth:`Controller.render`) when the env renders RGB frames, else
        the env's own ``render()``."""
        if self.env.render_mode == "rgb_array":
            return self.controller.render(self.env)
        return self.env.render()

    def close(self) -> None:
        self.env.close()


class NullPolicy:
    """``predict`` for :class:`ControllerEnv` in a VecEnv: the ignored action 0 for every env of the batch of
    observations (SB3's ``evaluate_policy(NULL_POLICY, vec_env)``)."""

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        if isinstance(observation, Mapping):
            observation = next(iter(observation.values()))
        shape = np.shape(observation)
        return np.zeros(shape[:1] if shape else (), dtype=np.int64), state


NULL_POLICY = NullPolicy()
