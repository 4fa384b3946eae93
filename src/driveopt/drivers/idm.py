"""highway-env's own IDM/MOBIL driver on the ego: the rule-based reference every optimiser is compared with."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from driveopt.drivers.base import Decision, DriverSpec

IDLE_ACTION = np.zeros(2, dtype=np.float32)  # the env steps with it; the IDM vehicle ignores actions


def hand_ego_to_idm(env: Any, v_des: float) -> None:
    """Replace the ego by highway-env's IDM/MOBIL vehicle aiming at ``v_des`` [m/s] (it ignores the actions it is sent)."""
    from highway_env.vehicle.behavior import IDMVehicle

    sim = env.unwrapped
    ego = sim.vehicle
    lane = sim.road.network.get_closest_lane_index(ego.position, ego.heading)
    driver = IDMVehicle(sim.road, ego.position, ego.heading, ego.speed, target_lane_index=lane, target_speed=v_des)
    sim.road.vehicles[sim.road.vehicles.index(ego)] = driver
    sim.vehicle = driver


class IDMDriver:
    """Hands the ego to highway-env's IDM/MOBIL vehicle at reset; every step is the idle action."""

    compile_seconds = 0.0

    def __init__(self, name: str = "idm") -> None:
        self.name = name

    def reset(self, env: Any, scenario: Any, seed: int) -> None:
        hand_ego_to_idm(env, scenario.v_des)

    def act(self, env: Any) -> Decision:
        return Decision(IDLE_ACTION)


@dataclasses.dataclass(frozen=True)
class IDMSpec(DriverSpec):
    def driver(self) -> IDMDriver:
        return IDMDriver(self.name)
