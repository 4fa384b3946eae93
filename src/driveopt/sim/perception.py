"""From the simulator to the planner: the current state as a :class:`~driveopt.scene.Scene`, read once per step.

:func:`perceive` reads ``env.unwrapped`` once: the ego in road coordinates (see
:mod:`driveopt.sim.road_frame`), the driving lanes at the ego's position, and every other vehicle
and collidable road object with its actual length and width. It returns the planning scene and the
ego's speed and body heading for the controller (:func:`driveopt.sim.control.track`).

The ego's velocity in the scene points along its course (body heading + the slip angle of the
steering applied now), as the simulator integrates it, so a plan starts with the lateral velocity
the car has; the plans leave their lateral acceleration free (``qp.initial_lateral_acceleration``)
because the slip angle is a command that can jump every period. With the velocity along the body
heading instead, the lateral motion of the last command was forgotten at every replan and the car
followed only the slow start of each plan (sideways at about a quarter of the planned
rate, and slow drifts across lanes).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from driveopt.observation import ObservationError
from driveopt.scene import EgoState, Neighbour, ProblemError, Scene
from driveopt.sim.control import EgoKinematics
from driveopt.sim.road_frame import Motion, driving_lanes, road_geometry, vehicle_motion
from driveopt.sim.scenarios import Scenario


class Perception(NamedTuple):
    """What one closed-loop step knows of the world."""

    scene: Scene  # planning scene: the ego's velocity along its course
    kinematics: EgoKinematics  # the ego's speed [m/s] and body heading [rad], for the controller


def _read(env: Any, scenario: Scenario) -> tuple[Scene, Motion]:
    """(scene, the ego's motion) of the current simulator state."""
    sim = env.unwrapped
    ego_vehicle = sim.vehicle
    if ego_vehicle is None or sim.road is None:
        raise ObservationError("the env has no road or ego vehicle: call env.reset(seed=...) first")
    lanes = driving_lanes(sim.road.network, float(ego_vehicle.position[0]))
    road = road_geometry(lanes)
    reference = lanes[0]
    try:
        me = vehicle_motion(ego_vehicle, reference)
        ego = EgoState(x=me.x, y=me.y, vx=me.vx, vy=me.vy, ax=me.ax, ay=me.ay, length=me.length, width=me.width,
                       yaw=me.heading)
        neighbours = []
        others = [v for v in sim.road.vehicles if v is not ego_vehicle]
        others += [o for o in sim.road.objects if getattr(o, "collidable", True)]
        for other in others:
            m = vehicle_motion(other, reference)
            accel = (m.ax * m.vx + m.ay * m.vy) / m.speed if m.speed > 1e-6 else 0.0  # along the velocity
            neighbours.append(
                Neighbour(x=m.x, y=m.y, vx=m.vx, vy=m.vy, length=m.length, width=m.width, yaw=m.heading, accel=accel)
            )
        scene = Scene(ego=ego, road=road, neighbours=tuple(neighbours), v_des=scenario.v_des, name=scenario.name)
    except ProblemError as exc:
        raise ObservationError(f"simulator state at t = {sim.steps / sim.config['simulation_frequency']:.2f} s: {exc}") from None
    return scene, me


def scene_from_env(env: Any, scenario: Scenario) -> Scene:
    """Scene of the current simulator state (``v_des``, name: the scenario's)."""
    return _read(env, scenario)[0]


def perceive(env: Any, scenario: Scenario) -> Perception:
    """The planning scene and the ego's kinematics, read once."""
    scene, me = _read(env, scenario)
    return Perception(scene, EgoKinematics(speed=me.speed, heading=me.heading))
