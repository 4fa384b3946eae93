"""A call at every simulation step of highway-env's ego, between the env's policy steps.

highway-env holds a policy step's action for all ``simulation_frequency // policy_frequency`` simulation steps of
the period (15 at upstream's 1 Hz envs): ``AbstractEnv._simulate`` hands the action to the ego once, then every
simulation step calls ``road.act()``, which calls each vehicle's ``act()`` without an action (keep the stored one),
and ``road.step``. Upstream's own controlled vehicles steer anew in that call at every simulation step; a car
driven by ``ContinuousAction`` cannot. :func:`install` gives the ego that call: after the vehicle's own ``act``
(which stores an action handed to it), ``hook.on_step(vehicle)`` may replace the stored action for this simulation
step.

The vehicle refers to the hook weakly, so copies of the env (``copy.deepcopy``) do not copy the hook and its owner
with it; a copy's vehicle calls the same hook, which acts only for the vehicle it was installed on.
"""

from __future__ import annotations

import types
import weakref
from typing import Any, Protocol

_ATTRIBUTE = "_driveopt_step_hook"


class StepHook(Protocol):
    def on_step(self, vehicle: Any) -> None:
        """Called after ``vehicle.act()`` at each simulation step; may set ``vehicle.action``."""


def _act(vehicle: Any, action: Any = None) -> None:
    type(vehicle).act(vehicle, action)
    if action is None:  # road.act(): one call per simulation step
        reference = vehicle.__dict__.get(_ATTRIBUTE)
        hook = reference() if reference is not None else None
        if hook is not None:
            hook.on_step(vehicle)


def install(vehicle: Any, hook: StepHook) -> None:
    """Make ``hook.on_step(vehicle)`` run at every simulation step of ``vehicle`` (replacing a hook installed before).
    The hook lives as long as its owner keeps it: the vehicle holds it weakly."""
    vehicle.__dict__[_ATTRIBUTE] = weakref.ref(hook)
    vehicle.act = types.MethodType(_act, vehicle)


def remove(vehicle: Any) -> None:
    """``vehicle`` acting as its class does again."""
    vehicle.__dict__.pop(_ATTRIBUTE, None)
    vehicle.__dict__.pop("act", None)
