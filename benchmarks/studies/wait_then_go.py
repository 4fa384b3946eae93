"""How many episodes of upstream highway-env's junction envs any car could finish by waiting at the junction's entry
and then going, with the env's own traffic (which reacts to it as it reacts to the planner's car):

    python benchmarks/studies/wait_then_go.py --out OUT.json [--envs intersection-v0 roundabout-v0] [--episodes 20]
        [--waits-step 0.25] [--acceleration 4.5] [--lateral 7] [--inside FRACTION]

For each seed and each wait w = 0, step, 2 step, ... the episode is driven by a scripted car on the route's lanes
(the ego's route, else the env's destination: :func:`arrival_ceiling.route_roads`). It follows the lanes by pure
pursuit, tracked at every simulation step (:mod:`driveopt.sim.step_hook`, as the controller tracks its plans), and
sets its speed by IDM (highway-env's centre-to-centre distance, standstill distance and time headway;
``--acceleration`` [m/s^2] at most, braking at most as ContinuousAction allows, 5 m/s^2) towards the lanes' speed
limit, lowered where a curve within 15 m needs it (``--lateral`` [m/s^2], the planner's centripetal bound), behind
the nearest car ahead on its lanes heading along them or just ahead of it heading its way, and, until w seconds have
passed, behind a standing car at the junction's entry: the start of the first road of the route whose end other roads
also join (intersection-v0: the turn through the junction; roundabout-v0: the entry lane onto the ring). Cars
crossing its lanes are not looked at: a wait either clears them or the episode collides. With ``--inside F`` the car
stops a second time, F along that road, until a second wait w2 >= w (every pair on the grid). An episode counts as
finishable when some wait arrives as the upstream table counts arrivals (``upstream_roads.arrived``) with no
collision; the earliest such wait is reported. This bounds what a driver that waits at those places can reach with
these envs' traffic: not a bound on every driver (one that creeps, or takes closer gaps than IDM's, may do better),
but one measured with the traffic's own reactions rather than predicted.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from driveopt.sim.lane_graph import wrap_angle

sys.path.insert(0, str(Path(__file__).resolve().parent))

from arrival_ceiling import route_roads  # noqa: E402
from upstream_roads import arrived, clock, make_env  # noqa: E402

JUNCTION_ENVS = ("intersection-v0", "roundabout-v0")
STEP = 0.5  # [m] spacing of the path's samples
LOOKAHEAD_TIME = 0.6  # [s] pure pursuit looks this far ahead at the car's speed ...
MIN_LOOKAHEAD = 4.0  # [m] ... and at least this far
CURVE_PREVIEW = 15.0  # [m] the speed limit is lowered for the sharpest curve within this distance ahead
LEADER_REACH = 25.0  # [m] a car this close ahead of the car's own heading, within ON_PATH across and heading its way,
# is followed too (one going straight on ahead of a car turning off the same entry)
CHORD = 5.0  # [m] the path's curvature is read over chords twice this long
ON_PATH = 2.0  # [m] a car within this lateral distance of the path, heading along it (within 45 degrees), is ahead


class RoutePath:
    """The route's lanes as a polyline: positions (P, 2) [m], headings (P,) [rad], arc lengths (P,) [m], curvature
    (P,) [1/m], speed limits (P,) [m/s]; the wait line's arc length [m]."""

    def __init__(self, sim) -> None:
        network, ego = sim.road.network, sim.vehicle
        roads = route_roads(sim)
        lanes, previous_end = [], None
        for k, road in enumerate(roads):
            candidates = network.graph[road[0]][road[1]]
            if k == 0:
                lane = network.get_lane(ego.lane_index)
            else:
                lane = min(candidates, key=lambda c: float(np.linalg.norm(c.position(0.0, 0.0) - previous_end)))
            lanes.append((road, lane))
            previous_end = lane.position(lane.length, 0.0)
        points, headings, limits, starts = [], [], [], []
        offset = 0.0
        for k, (road, lane) in enumerate(lanes):
            s0 = float(lane.local_coordinates(np.asarray(ego.position, dtype=float))[0]) if k == 0 else 0.0
            s = np.arange(max(s0 - 10.0, 0.0) if k == 0 else 0.0, lane.length, STEP)
            starts.append(offset - (s[0] if len(s) else 0.0))
            for x in s:
                points.append(lane.position(float(x), 0.0))
                headings.append(lane.heading_at(float(x)))
                limits.append(float(lane.speed_limit or 20.0))
            offset += len(s) * STEP
        self.xy = np.asarray(points, dtype=float)
        self.heading = np.unwrap(np.asarray(headings, dtype=float))
        self.s = STEP * np.arange(len(points), dtype=float)
        # curvature over a chord of 2 CHORD: lanes meet with a kink at roundabout-v0's ring (its entry ends 5.6 m from
        # the ring lane's start, 47 degrees away), which pure pursuit rounds off over its look-ahead
        k = int(round(CHORD / STEP))
        ahead, behind = np.roll(self.xy, -k, axis=0), np.roll(self.xy, k, axis=0)
        ahead[-k:], behind[:k] = self.xy[-1], self.xy[0]
        chord = np.unwrap(np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0]))
        self.curvature = np.abs(np.gradient(chord, STEP))
        self.limit = np.asarray(limits, dtype=float)
        self.roads = [road for road, _ in lanes]
        incoming: dict[str, int] = {}
        for ends in network.graph.values():
            for end in ends:
                incoming[end] = incoming.get(end, 0) + 1
        first_joined = next((k for k, road in enumerate(self.roads) if incoming.get(road[1], 0) > 1), 0)
        self.wait_s = starts[first_joined]  # [m] the junction's entry along the path
        self.junction_length = float(lanes[first_joined][1].length)  # [m] the route's road through the junction

    def locate(self, position: np.ndarray) -> tuple[float, float, float]:
        """(arc length [m], lateral distance [m], path heading [rad]) of the path's sample nearest ``position``."""
        d = np.linalg.norm(self.xy - position, axis=1)
        k = int(np.argmin(d))
        return float(self.s[k]), float(d[k]), float(self.heading[k])


class WaitThenGo:
    """The scripted car's command at each simulation step (a step hook, and the env's action at each policy step)."""

    def __init__(self, sim, path: RoutePath, wait: float, acceleration: float, lateral: float,
                 inside: tuple[float, float] | None = None) -> None:
        from driveopt.sim.control import BicycleModel
        from highway_env.vehicle.behavior import IDMVehicle

        self.sim, self.path, self.wait, self.a_max, self.lateral = sim, path, wait, acceleration, lateral
        self.inside = inside  # (arc length [m], wait [s]) of a second stop, inside the junction, or None
        self.gap0, self.headway = IDMVehicle.DISTANCE_WANTED, IDMVehicle.TIME_WANTED
        self.model = BicycleModel.from_env(sim)  # the car's length and ContinuousAction's ranges

    def command(self) -> tuple[float, float]:
        """(acceleration [m/s^2], steering angle [rad]) for the ego now."""
        ego, path = self.sim.vehicle, self.path
        position, speed = np.asarray(ego.position, dtype=float), float(ego.speed)
        s, _, _ = path.locate(position)
        # steering: pure pursuit of the path's point a look-ahead further on
        target = int(round((s + max(MIN_LOOKAHEAD, LOOKAHEAD_TIME * speed)) / STEP))
        to_point = path.xy[min(target, len(path.s) - 1)] - position
        alpha = wrap_angle(math.atan2(to_point[1], to_point[0]) - float(ego.heading))
        distance = max(float(np.linalg.norm(to_point)), 1e-3)
        steering = math.atan(2.0 * self.model.length * math.sin(alpha) / distance)
        # speed: IDM to the limit, lowered for the curves ahead, behind the car ahead and the wait line
        ahead = (path.s >= s) & (path.s <= s + CURVE_PREVIEW)
        kappa = float(np.max(path.curvature[ahead], initial=0.0))
        limit = float(np.interp(s, path.s, path.limit))
        v0 = min(limit, math.sqrt(self.lateral / kappa)) if kappa > 1e-6 else limit
        gaps = []
        for other in self.sim.road.vehicles:
            if other is ego:
                continue
            so, lateral, heading = path.locate(np.asarray(other.position, dtype=float))
            turn = abs(wrap_angle(float(other.heading) - heading))  # [rad] against the path
            relative = np.asarray(other.position, dtype=float) - position
            along = relative[0] * math.cos(ego.heading) + relative[1] * math.sin(ego.heading)
            across = -relative[0] * math.sin(ego.heading) + relative[1] * math.cos(ego.heading)
            same_way = abs(wrap_angle(float(other.heading) - float(ego.heading)))  # [rad] against the car
            if so > s and lateral < ON_PATH and turn < math.pi / 4:  # ahead on the path
                gaps.append((so - s, float(other.speed)))
            elif 0.0 < along < LEADER_REACH and abs(across) < ON_PATH and same_way < math.pi / 4:  # ahead of the car
                gaps.append((along, float(other.speed)))
        half = 0.5 * self.model.length  # [m]
        stops = [(path.wait_s - half, self.wait)]  # [m] where the car's centre stands, its front at the
        # entry, until [s]; then where it stands inside the junction
        if self.inside is not None:
            stops.append((self.inside[0] - half, self.inside[1]))
        for line, until in stops:  # a standing car whose centre lies IDM's standstill distance beyond
            if clock(self.sim) < until and s < line:
                gaps.append((line - s + self.gap0, 0.0))
                break
        acceleration = self.a_max * (1.0 - (speed / max(v0, 0.1)) ** 4)
        if gaps:  # (centre-to-centre distance [m], the car's speed [m/s]), as highway-env's IDM measures it
            gap, other_speed = min(gaps)
            wanted = (self.gap0 + speed * self.headway
                      + speed * (speed - other_speed) / (2.0 * math.sqrt(self.a_max * 3.0)))
            acceleration -= self.a_max * (max(wanted, 0.0) / max(gap, 0.1)) ** 2
        if speed <= 0.0 and acceleration < 0.0:
            acceleration = 0.0
        return float(np.clip(acceleration, self.model.acceleration_range[0], self.a_max)), steering

    def on_step(self, vehicle) -> None:
        acceleration, steering = self.command()
        vehicle.action = {"acceleration": acceleration, "steering": steering}

    def action(self) -> np.ndarray:
        """The command as the env's normalised ContinuousAction."""
        from driveopt.sim.control import to_action

        return to_action(*self.command(), self.model)


def drive(env, seed: int, wait: float, acceleration: float, lateral: float, traffic=None,
          inside: tuple[float, float] | None = None) -> dict:
    """One episode of ``env`` at ``seed`` driven by :class:`WaitThenGo` waiting ``wait`` [s] at the entry and, with
    ``inside`` = (fraction, wait [s]), again that fraction along the route's road through the junction, with
    upstream's traffic constants ``traffic`` restored first (``driveopt.sim.traffic``; intersection-v0 changes them for
    the process)."""
    from driveopt.sim import step_hook
    from driveopt.sim.traffic import restore_traffic_constants

    if traffic is not None:
        restore_traffic_constants(traffic)
    env.reset(seed=seed)
    sim = env.unwrapped
    path = RoutePath(sim)
    stop = None if inside is None else (path.wait_s + inside[0] * path.junction_length, inside[1])
    driver = WaitThenGo(sim, path, wait, acceleration, lateral, stop)
    step_hook.install(sim.vehicle, driver)
    roads = [list(road) for road in path.roads]
    reached = collided = False
    info: dict = {}
    for _ in range(round(float(sim.config["duration"]) * sim.config["policy_frequency"])):
        _, _, terminated, truncated, info = env.step(driver.action())
        collided |= bool(sim.vehicle.crashed)
        reached |= list(sim.vehicle.lane_index[:2]) == roads[-1]
        if terminated or truncated or collided:
            break
    arrival = bool(arrived(sim, roads, info, reached)) and not collided
    return {"wait": wait, **({} if inside is None else {"inside_wait": inside[1]}), "arrived": arrival,
            "collided": collided, "time": clock(sim)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="JSON file for the results (written after each seed)")
    parser.add_argument("--envs", nargs="+", default=list(JUNCTION_ENVS), choices=JUNCTION_ENVS)
    parser.add_argument("--episodes", type=int, default=20, help="seeds 0 .. episodes - 1")
    parser.add_argument("--waits-step", type=float, default=0.25, help="[s] between the waits tried")
    parser.add_argument("--acceleration", type=float, default=4.5, help="[m/s^2] at most (the planner's a_max)")
    parser.add_argument("--lateral", type=float, default=7.0, help="[m/s^2] centripetal bound (the planner's)")
    parser.add_argument("--inside", type=float, default=None, metavar="FRACTION",
                        help="also stop this fraction along the route's road through the junction (0-1), for every "
                             "wait there from the entry's wait on")
    args = parser.parse_args(argv)
    if args.episodes < 1 or not args.waits_step > 0 or not args.acceleration > 0 or not args.lateral > 0:
        parser.error("--episodes, --waits-step, --acceleration and --lateral must be positive")
    if args.inside is not None and not 0.0 < args.inside < 1.0:
        parser.error("--inside must be a fraction in (0, 1)")
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    from driveopt.cli import stop_cleanly_on_signals
    from driveopt.files import write_json

    from driveopt.sim.traffic import restore_traffic_constants, traffic_constants

    stop_cleanly_on_signals()
    traffic = traffic_constants()  # before any env is made
    results: dict = {}
    command = "python benchmarks/studies/wait_then_go.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for env_id in args.envs:
        restore_traffic_constants(traffic)
        env = make_env(env_id)
        duration = float(env.unwrapped.config["duration"])
        waits = np.arange(0.0, duration, args.waits_step)
        episodes = []
        for seed in range(args.episodes):
            start = time.perf_counter()
            tried, earliest = 0, None
            plans = [(w, None) for w in waits] if args.inside is None else \
                [(w, (args.inside, float(w2))) for w in waits for w2 in waits if w2 >= w]
            for wait, inside in plans:
                tried += 1
                episode = drive(env, seed, float(wait), args.acceleration, args.lateral, traffic, inside)
                if episode["arrived"]:
                    earliest = episode
                    break
            episodes.append({"seed": seed, "finishable": earliest is not None, "earliest": earliest,
                             "waits_tried": tried})
            print(f"{env_id} seed {seed}: " + (f"arrives waiting {earliest['wait']:g} s (at {earliest['time']:.1f} s)"
                  if earliest else f"no wait of {tried} arrives") + f" [{time.perf_counter() - start:.0f} s]",
                  flush=True)
            results[env_id] = {"duration_s": duration, "episodes": episodes,
                               "finishable": sum(e["finishable"] for e in episodes)}
            write_json(args.out, {"command": command, "acceleration": args.acceleration, "lateral": args.lateral,
                                  "waits_step": args.waits_step, "inside": args.inside, "results": results})
        env.close()
        print(f"{env_id}: {results[env_id]['finishable']} of {len(episodes)} finishable by waiting "
              + ("once" if args.inside is None else "at the entry and inside"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
