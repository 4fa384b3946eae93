"""From the simulator to the planner: a :class:`~driveopt.problem.Scene` of the current state.

:func:`scene_from_env` reads ``env.unwrapped``: the ego in road coordinates (velocity along its
course, acceleration it is applying — see :mod:`driveopt.sim.road_frame`), the driving lanes
at the ego's position, and every other vehicle and collidable road object with its actual
length and width. ``build_problem(scene)`` then predicts the nearest neighbours with constant
velocity and sizes their collision ellipses from those lengths and widths, and computes the
55-dim observation (:mod:`driveopt.observation`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from driveopt.observation import (  # noqa: F401  (re-exported)
    DUMMY_DX,
    EGO_FEATURES,
    NEIGHBOUR_FEATURES,
    NUM_NEIGHBOURS,
    OBSERVATION_DIM,
    ObservationError,
    check_observation,
    is_dummy,
    observation_vector,
    split_observation,
)
from driveopt.problem import EgoState, Neighbour, ProblemError, Scene
from driveopt.sim.road_frame import driving_lanes, road_geometry, vehicle_motion
from driveopt.sim.scenarios import Scenario


def scene_from_env(env: Any, scenario: Scenario) -> Scene:
    """Planning scene of the current simulator state (road frame; ``v_des`` and name from the scenario)."""
    sim = env.unwrapped
    ego_vehicle = sim.vehicle
    if ego_vehicle is None or sim.road is None:
        raise ObservationError("the env has no road or ego vehicle: call env.reset(seed=...) first")
    lanes = driving_lanes(sim.road.network, float(ego_vehicle.position[0]))
    road = road_geometry(lanes)
    reference = lanes[0]
    try:
        me = vehicle_motion(ego_vehicle, reference)
        ego = EgoState(x=me.x, y=me.y, vx=me.vx, vy=me.vy, ax=me.ax, ay=me.ay, length=me.length, width=me.width)
        neighbours = []
        others = [v for v in sim.road.vehicles if v is not ego_vehicle]
        others += [o for o in sim.road.objects if getattr(o, "collidable", True)]
        for other in others:
            m = vehicle_motion(other, reference)
            accel = (m.ax * m.vx + m.ay * m.vy) / m.speed if m.speed > 1e-6 else 0.0  # along the velocity
            neighbours.append(
                Neighbour(x=m.x, y=m.y, vx=m.vx, vy=m.vy, length=m.length, width=m.width, yaw=m.heading, accel=accel)
            )
        return Scene(ego=ego, road=road, neighbours=tuple(neighbours), v_des=scenario.v_des, name=scenario.name)
    except ProblemError as exc:
        raise ObservationError(f"simulator state at t = {sim.steps / sim.config['simulation_frequency']:.2f} s: {exc}") from None


def observation_from_env(env: Any, scenario: Scenario, num_neighbours: int = NUM_NEIGHBOURS) -> np.ndarray:
    """Observation vector of the current simulator state."""
    return observation_vector(scene_from_env(env, scenario), num_neighbours)
