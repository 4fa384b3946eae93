"""highway-env's own IDM/MOBIL driver on the ego: the rule-based reference every optimiser is compared with.

A route (the task's node names, e.g. ``("0", "1", "2", "exit")``) is handed to highway-env's own route following
(``ControlledVehicle.route``, read by ``RoadNetwork.next_lane`` at the end of each lane); without one the vehicle
keeps the ego's own route, if it had one. A route that does not continue from the ego's road is refused
(:class:`IDMRouteError`), never ignored. MOBIL does not change lanes for a route: at a split the vehicle turns from
the lane it is in onto the route's nearest lane (highway-env's behaviour).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from driveopt.drivers.base import Decision, DriverSpec
from driveopt.errors import DriveoptError
from driveopt.sim.lane_graph import route_roads

IDLE_ACTION = np.zeros(2, dtype=np.float32)  # the env steps with it; the IDM vehicle ignores actions


class IDMRouteError(DriveoptError):
    """A route highway-env's IDM vehicle cannot follow from where the ego is."""


def idm_route(lane: tuple, route: Any) -> list[tuple] | None:
    """highway-env's ``Route`` (lane indices) for a vehicle in ``lane`` following ``route`` (node names); None for None.
    IDMRouteError when the route neither passes through the lane's road nor starts where it ends."""
    if route is None:
        return None
    roads = list(route_roads(route))
    here = (lane[0], lane[1])
    if here in roads:
        after = roads[roads.index(here) + 1:]
    elif roads and roads[0][0] == here[1]:
        after = roads
    else:
        raise IDMRouteError(f"route {list(route)} neither passes through the ego's road {here!r} nor starts at its end "
                            f"node {here[1]!r}: highway-env's IDM vehicle cannot follow it from there")
    return [tuple(lane)] + [(a, b, None) for a, b in after]


def hand_ego_to_idm(env: Any, v_des: float, route: Any = None) -> None:
    """Replace the ego by highway-env's IDM/MOBIL vehicle aiming at ``v_des`` [m/s] (it ignores the actions it is sent),
    following ``route`` (node names; None: the ego's own route, if any) with highway-env's route following."""
    from highway_env.vehicle.behavior import IDMVehicle

    sim = env.unwrapped
    ego = sim.vehicle
    lane = sim.road.network.get_closest_lane_index(ego.position, ego.heading)
    planned = idm_route(lane, route)
    if planned is None and getattr(ego, "route", None):
        planned = list(ego.route)
    driver = IDMVehicle(sim.road, ego.position, ego.heading, ego.speed, target_lane_index=lane, target_speed=v_des,
                        route=planned)
    sim.road.vehicles[sim.road.vehicles.index(ego)] = driver
    sim.vehicle = driver


class IDMDriver:
    """Hands the ego to highway-env's IDM/MOBIL vehicle at reset; every step is the idle action."""

    compile_seconds = 0.0

    def __init__(self, name: str = "idm") -> None:
        self.name = name

    def reset(self, env: Any, scenario: Any, seed: int) -> None:
        hand_ego_to_idm(env, scenario.v_des, getattr(scenario, "route", None))

    def act(self, env: Any) -> Decision:
        return Decision(IDLE_ACTION)


@dataclasses.dataclass(frozen=True)
class IDMSpec(DriverSpec):
    def driver(self) -> IDMDriver:
        return IDMDriver(self.name)
