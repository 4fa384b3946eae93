"""A faster drop-in for upstream's ``Road`` on straight roads along the x axis: same results, fewer Python loops.

Upstream finds each vehicle's leader and follower by projecting every other vehicle on the lane one at a time
(``Road.neighbour_vehicles``, called several times per vehicle and simulation step by IDM and MOBIL) and tests
collisions pair by pair (``Road.step``): with 50 vehicles on four lanes these two loops are ~70% of the
simulation time. :class:`FastRoad` does the same arithmetic on arrays:

- ``neighbour_vehicles``: on a lane whose direction is exactly (1, 0), upstream's lane coordinates of a
  position p are exactly (p_x - start_x, p_y - start_y) (the dot products with (1, 0) and (-0, 1) add only
  zeros), so the array version computes bit-identical coordinates and applies upstream's on-lane test
  (margin 1 m) and tie rules (the last of equal leaders, the first of equal followers, in road order).
- ``step``: a conservative array pre-test (centre distance within the sum of half diagonals plus the faster
  car's travel in ``dt`` plus 1 m) keeps the pairs upstream's own spherical pre-test could pass, and upstream's
  ``handle_collisions`` runs on exactly those pairs in upstream's order. Pairs left out are ones upstream
  would have found apart, for which it changes nothing.

Anything else (curved or tilted lanes, connected-lane search, road objects) takes upstream's code path.
``tests/test_fast_road.py`` checks that whole episodes are identical with either road.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from highway_env.road.lane import AbstractLane, StraightLane
from highway_env.road.road import Road

PAIR_MARGIN = 1.0  # [m] slack of the array collision pre-test over upstream's spherical one
LANE_MARGIN = 1.0  # [m] upstream's lateral margin when it looks for neighbours on a lane


def along_x(lane: AbstractLane) -> bool:
    """Whether ``lane`` is straight with direction exactly (1, 0): its lane coordinates are plain differences."""
    return type(lane) is StraightLane and lane.direction[0] == 1.0 and lane.direction[1] == 0.0


class FastRoad(Road):
    """Upstream's ``Road`` with array versions of ``neighbour_vehicles`` and the collision pass (module docstring)."""

    @classmethod
    def like(cls, road: Road) -> "FastRoad":
        """A FastRoad with ``road``'s network, vehicles, objects, generator and options."""
        return cls(network=road.network, vehicles=road.vehicles, road_objects=road.objects, np_random=road.np_random,
                   record_history=road.record_history,
                   neighbour_vehicles_connected_lanes=road.neighbour_vehicles_connected_lanes)

    def _arrays_apply(self) -> bool:
        return not self.objects and not self.neighbour_vehicles_connected_lanes

    def _positions(self) -> np.ndarray:
        """(N, 2) [m] positions of ``self.vehicles``; fixed while the vehicles act, so cached during ``act``."""
        cached = getattr(self, "_acting_positions", None)
        if cached is not None:
            return cached
        return np.array([v.position for v in self.vehicles], dtype=float).reshape(-1, 2)

    def act(self) -> None:
        """Upstream's act (each vehicle decides) with the positions gathered once for the neighbour searches."""
        self._acting_positions = self._positions() if self._arrays_apply() else None
        try:
            super().act()
        finally:
            self._acting_positions = None

    def neighbour_vehicles(self, vehicle: Any, lane_index: Any = None) -> tuple[Any, Any]:
        """Upstream's leader and follower of ``vehicle`` on ``lane_index`` (default: its own lane)."""
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        lane = self.network.get_lane(lane_index)
        if not (self._arrays_apply() and along_x(lane)) or not self.vehicles:
            return super().neighbour_vehicles(vehicle, lane_index)
        positions = self._positions()
        s = float(vehicle.position[0] - lane.start[0])
        s_v = positions[:, 0] - lane.start[0]
        lateral = positions[:, 1] - lane.start[1]
        on_lane = ((np.abs(lateral) <= lane.width / 2 + LANE_MARGIN)
                   & (-lane.VEHICLE_LENGTH <= s_v) & (s_v < lane.length + lane.VEHICLE_LENGTH))
        for i, other in enumerate(self.vehicles):  # identity, as upstream (a vehicle need not be on the road)
            if other is vehicle:
                on_lane[i] = False
                break
        ahead = np.flatnonzero(on_lane & (s_v >= s))
        behind = np.flatnonzero(on_lane & (s_v < s))
        front = rear = None
        if ahead.size:
            nearest = ahead[s_v[ahead] == s_v[ahead].min()]
            front = self.vehicles[nearest[-1]]  # upstream replaces on ties (<=): the last in road order
        if behind.size:
            nearest = behind[s_v[behind] == s_v[behind].max()]
            rear = self.vehicles[nearest[0]]  # upstream keeps on ties (>): the first in road order
        return front, rear

    def step(self, dt: float) -> None:
        """Step every vehicle, then upstream's collision handling on the pairs that can touch, in upstream's order."""
        if not self._arrays_apply():
            return super().step(dt)
        for vehicle in self.vehicles:
            vehicle.step(dt)
        if len(self.vehicles) < 2:
            return
        positions = self._positions()
        half_diagonal = np.array([v.diagonal for v in self.vehicles]) / 2
        travel = np.array([abs(v.speed) for v in self.vehicles]) * dt
        reach = half_diagonal + travel
        distance = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
        close = np.triu(distance <= reach[:, None] + reach[None, :] + PAIR_MARGIN, k=1)
        for i, j in zip(*np.nonzero(close)):  # row-major: upstream's loop order
            self.vehicles[i].handle_collisions(self.vehicles[j], dt)
