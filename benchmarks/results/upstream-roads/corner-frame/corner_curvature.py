"""The frame's corner pieces at a roundabout: their true curvature, how far their longitudinal is from arc length, and
the least peak curvature other Bezier arms would give.

    python benchmarks/results/upstream-roads/corner-frame/corner_curvature.py roundabout-v0

For each corner piece of the route's frame (seed 0): the peak of the reference line's curvature per metre of arc, its
arc length against the piece's longitudinal length, the range of ds/dl (arc length per unit of longitudinal), and,
over a grid of the two inner control points' distances (fractions of the chord along each lane's direction), the
least peak curvature whose points 0.5 m either side of the reference line lie on a lane of the road (the arms at a
third of the chord keep 0.53 m at roundabout-v0).
"""

import sys

import numpy as np

import driveopt
from driveopt.sim.corner_lane import CornerLane
from driveopt.sim.lane_graph import driving_lanes
from driveopt.sim.road_frame import ego_frame


def arc_profile(corner: CornerLane) -> tuple[float, float, float, float]:
    """(peak |curvature| [1/m] per metre of arc, arc length [m], min and max ds/dl)."""
    u = np.linspace(0.0, 1.0, 2001)
    points, _ = corner._curve(u)
    segment = np.hypot(*np.diff(points, axis=0).T)
    heading = np.unwrap(np.arctan2(*np.diff(points, axis=0).T[::-1]))
    curvature = np.diff(heading) / segment[1:]
    rate = segment / (corner.length / (len(u) - 1))
    return float(np.abs(curvature).max()), float(segment.sum()), float(rate.min()), float(rate.max())


def on_road(network, corner: CornerLane, offset: float = 0.5) -> bool:
    """Whether points ``offset`` [m] either side of the reference line, at 161 points along it, lie on a driving lane
    (within its length and half its width)."""
    lanes = [lane for frm, tos in network.graph.items() for to in tos for _, lane in driving_lanes(network, (frm, to))]

    def on_a_lane(point):
        for lane in lanes:
            longitudinal, lateral = lane.local_coordinates(point)
            if 0.0 <= longitudinal <= lane.length and abs(lateral) <= 0.5 * lane.width_at(longitudinal):
                return True
        return False

    return all(on_a_lane(corner.position(x, d)) for x in np.linspace(0.0, corner.length, 161) for d in (-offset, offset))


def main(env_id: str) -> None:
    env = driveopt.gym_make(env_id, config={"action": {"type": "ContinuousAction"}})
    env.reset(seed=0)
    controller = driveopt.Controller("idm")
    controller.reset(env, seed=0)
    network = env.unwrapped.road.network
    frame, _ = ego_frame(env.unwrapped, controller.task.route)
    for piece in (p for p in frame.pieces if isinstance(p.lane, CornerLane)):
        corner = piece.lane
        p0, p1, p2, p3 = controls = corner._controls.copy()
        peak, arc, low, high = arc_profile(corner)
        print(f"{piece.bands[0].road} -> {piece.bands[-1].road}: peak {peak:.3f} 1/m, arc {arc:.2f} m for a "
              f"longitudinal of {corner.length:.1f} m, ds/dl {low:.3f}-{high:.3f}")
        chord = np.linalg.norm(p3 - p0)
        leave, arrive = (p1 - p0) / np.linalg.norm(p1 - p0), (p3 - p2) / np.linalg.norm(p3 - p2)
        trials = []
        for fa in np.linspace(0.1, 0.7, 25):
            for fb in np.linspace(0.1, 0.7, 25):
                corner._controls = np.stack([p0, p0 + fa * chord * leave, p3 - fb * chord * arrive, p3])
                trials.append((arc_profile(corner)[0], fa, fb))
        for peak, fa, fb in sorted(trials):
            corner._controls = np.stack([p0, p0 + fa * chord * leave, p3 - fb * chord * arrive, p3])
            if on_road(network, corner):
                _, arc, low, high = arc_profile(corner)
                print(f"  least on the road: peak {peak:.3f} 1/m with arms {fa:.3f} and {fb:.3f} of the chord "
                      f"(arc {arc:.2f} m, ds/dl {low:.3f}-{high:.3f})")
                break
        corner._controls = controls
    env.close()


if __name__ == "__main__":
    main(sys.argv[1])
