"""The per-simulation-step call on highway-env's ego (driveopt.sim.step_hook)."""

from __future__ import annotations

import copy
import gc

from driveopt.sim import step_hook


class _Vehicle:
    """highway-env's Vehicle.act: an action handed to it is stored, none keeps the stored one."""

    def __init__(self) -> None:
        self.action = {"steering": 0.0}

    def act(self, action=None):
        if action:
            self.action = action


class _Hook:
    def __init__(self) -> None:
        self.calls = []

    def on_step(self, vehicle) -> None:
        self.calls.append(vehicle)
        vehicle.action = {"steering": len(self.calls)}


def test_the_hook_runs_after_each_simulation_steps_act_and_may_replace_the_action():
    vehicle, hook = _Vehicle(), _Hook()
    step_hook.install(vehicle, hook)
    vehicle.act({"steering": 0.5})  # the env hands the policy's action over: stored, no hook
    assert vehicle.action == {"steering": 0.5} and hook.calls == []
    vehicle.act()  # road.act() at each simulation step
    vehicle.act()
    assert hook.calls == [vehicle, vehicle] and vehicle.action == {"steering": 2}
    step_hook.remove(vehicle)
    vehicle.act()
    assert len(hook.calls) == 2 and "act" not in vehicle.__dict__


def test_a_copied_vehicle_calls_the_hook_with_itself_and_does_not_copy_it():
    vehicle, hook = _Vehicle(), _Hook()
    step_hook.install(vehicle, hook)
    twin = copy.deepcopy(vehicle)
    twin.act()
    assert hook.calls == [twin] and twin.action == {"steering": 1} and vehicle.action == {"steering": 0.0}


def test_the_vehicle_does_not_keep_the_hook_alive():
    vehicle, hook = _Vehicle(), _Hook()
    step_hook.install(vehicle, hook)
    del hook
    gc.collect()
    vehicle.act()  # the owner dropped it: the vehicle acts as its class does
    assert vehicle.action == {"steering": 0.0}
