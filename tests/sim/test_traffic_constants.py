"""Upstream's traffic constants, restored after an env that changes them for the whole process."""

from __future__ import annotations

from highway_env.vehicle.behavior import IDMVehicle, LinearVehicle

import driveopt
from driveopt.sim.traffic import restore_traffic_constants, traffic_constants

NAMES = ("DISTANCE_WANTED", "COMFORT_ACC_MAX", "COMFORT_ACC_MIN")


def test_constants_intersection_v0_sets_for_the_process_are_restored():
    before = traffic_constants()
    upstream = tuple(before[IDMVehicle][name] for name in NAMES)
    linear = dict(vars(LinearVehicle))
    env = driveopt.gym_make("intersection-v0")
    env.reset(seed=0)
    env.close()
    assert tuple(getattr(IDMVehicle, name) for name in NAMES) == (7, 6, -3), "upstream's intersection-v0 sets these"
    IDMVehicle.SOMETHING_NEW = 1.0
    restore_traffic_constants(before)
    assert tuple(getattr(IDMVehicle, name) for name in NAMES) == upstream
    assert not hasattr(IDMVehicle, "SOMETHING_NEW")
    assert {k: v for k, v in vars(LinearVehicle).items() if k.isupper()} == \
        {k: v for k, v in linear.items() if k.isupper()}, "a subclass keeps its own constants"
