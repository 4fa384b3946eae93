"""The two direction promises of the planner over many problems: the fallback is a stop that never changes the sign of
the velocity, and no SUCCESS plan moves against the ego's direction of travel.

    python benchmarks/studies/stop_property.py --json out/stop_property.json --random 5000 --realistic 2000 \
        [--samples 64] [--iterations 2] [--projection-iterations 10] [--seed 0]

Plans ``--random`` problems drawn from the whole accepted range of the reliability property test
(tests/cli/test_reliability.py: any lane count and width, curvature, ego anywhere across the road at -40 to 40 m/s,
up to 16 neighbours anywhere) and ``--realistic`` ones of highway traffic (the ego near a lane centre at 0 to 35 m/s,
up to 16 neighbours near lane centres at 0 to 30 m/s), each with its own PRNG key, on a small planner (defaults: 64
samples, 2 sampler iterations, 10 projection iterations). Counts, per set:

- fallback violations, by promise: the speed never rises and never goes below zero; the stop starts where the ego is,
  at its speed, in its direction of travel (with its velocity where its course is within the stop's 0.5 lateral
  slope); it never moves against that direction (velocity or position); it ends at rest where the horizon allows;
  it stays within 72 degrees of the road; it stays on the road (or, off it, never moves further away);
- SUCCESS plans that move against the direction of travel beyond the feasibility tolerance: faster than
  ``sampler.residual_tolerance`` [m/s] against it at a node (the projection's course bound holds every velocity within a
  right angle of the direction of travel, and a SUCCESS plan's velocity residual is within that tolerance), or further
  behind the furthest point reached than that speed allows over the horizon (:func:`reversal_limits`); and, to show
  what is left inside the tolerance, those beyond float32 noise (``NOISE``) and the worst of them.

The first few problems of every violation are kept as problem files (``driveopt plan --problem``) with their key. The
JSON is written at the end, and on Ctrl-C with what was planned so far (``"interrupted": true``).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from driveopt.config import PlannerConfig
from driveopt.files import write_json
from driveopt.planner import PlanStatus, plan
from driveopt.problem import build_problem
from driveopt.scene import EgoState, Neighbour, Road, Scene, scene_to_dict

TOLERANCE = 1e-3  # [m/s], [m] float32 slack of the fallback's checks
FLOAT_SLACK = 1e-4  # [m/s], [m] a plan's numbers read out of the result against those the planner ranked
STOP_COURSE = 0.5  # [-] |vy| / speed up to which a stop starts on the ego's course (driveopt.fallback)
MAX_HEADING = math.radians(72.0)  # [rad] a stop's path stays within this of the road's direction
EXAMPLES = 3  # problems kept per violation
NOISE = 1e-3  # [m/s], [m] motion against the direction of travel beyond float32 noise (~1e-4 m/s at 100s of m)


def random_scene(rng: np.random.Generator) -> Scene:
    """Any accepted problem, as the reliability property test draws them."""
    neighbours = tuple(
        Neighbour(x=rng.uniform(-60, 150), y=rng.uniform(-6, 22), vx=rng.uniform(-2, 35), vy=rng.uniform(-2, 2),
                  length=rng.uniform(2, 14), width=rng.uniform(1.2, 3), accel=rng.uniform(-8, 3),
                  yaw=None if rng.random() < 0.5 else rng.uniform(-0.5, 0.5))
        for _ in range(rng.integers(0, 17)))
    ego = EgoState(x=0.0, y=rng.uniform(-15, 30), vx=rng.uniform(-40, 40), vy=rng.uniform(-3, 3),
                   ax=rng.uniform(-6, 6), ay=rng.uniform(-3, 3))
    road = Road(num_lanes=int(rng.integers(1, 6)), lane_width=rng.uniform(3, 5), curvature=rng.uniform(-0.02, 0.02))
    return Scene(ego=ego, road=road, neighbours=neighbours, v_des=rng.uniform(0, 40))


def realistic_scene(rng: np.random.Generator) -> Scene:
    """Highway traffic: the ego near a lane centre driving forwards, neighbours near lane centres."""
    road = Road(num_lanes=int(rng.integers(2, 6)))
    centres = road.lane_centers
    ego = EgoState(x=0.0, y=rng.choice(centres) + rng.uniform(-0.5, 0.5), vx=rng.uniform(0, 35), vy=rng.uniform(-0.5, 0.5),
                   ax=rng.uniform(-3, 2))
    neighbours = tuple(Neighbour(x=rng.uniform(-60, 150), y=rng.choice(centres) + rng.uniform(-0.3, 0.3),
                                 vx=rng.uniform(0, 30), accel=rng.uniform(-6, 1))
                       for _ in range(rng.integers(0, 17)))
    return Scene(ego=ego, road=road, neighbours=neighbours, v_des=rng.uniform(5, 35))


def fallback_violations(result, scene: Scene) -> list[str]:
    """The promises the fallback of ``result`` breaks for ``scene`` (road frame, ``x_offset`` the ego's x)."""
    fb, ego = result.fallback, scene.ego
    speed, vx, vy, x, y = (np.asarray(a, np.float64) for a in (fb.speed, fb.vx, fb.vy, fb.x, fb.y))
    if abs(ego.vx) > TOLERANCE:
        direction = math.copysign(1.0, ego.vx)
    else:  # standing: either way, but one way only
        direction = -1.0 if x[-1] < x[0] else 1.0
    broken = {
        "speed_rises": np.any(np.diff(speed) > TOLERANCE),
        "negative_speed": np.any(speed < -TOLERANCE),
        "start_position": abs(x[0] - ego.x) > TOLERANCE or abs(y[0] - ego.y) > TOLERANCE,
        "start_speed": abs(speed[0] - ego.speed) > TOLERANCE,
        "start_velocity": abs(ego.vy) <= STOP_COURSE * ego.speed and (abs(vx[0] - ego.vx) > TOLERANCE
                                                                       or abs(vy[0] - ego.vy) > TOLERANCE),
        "against_travel": np.any(direction * vx < -TOLERANCE) or np.any(direction * np.diff(x) < -TOLERANCE),
        "not_at_rest": ego.speed <= result.fallback_deceleration * float(fb.t[-1]) and speed[-1] > TOLERANCE,
        "turns_back": np.any(np.abs(vy) > math.tan(MAX_HEADING) * np.abs(vx) + TOLERANCE),
        "leaves_road": _leaves_road(y, ego.y, scene.lateral_bounds),
    }
    return [name for name, bad in broken.items() if bad]


def _leaves_road(y: np.ndarray, y0: float, bounds: tuple[float, float]) -> bool:
    """Whether a path of lateral positions ``y`` [m] from ``y0`` leaves the ``bounds`` [m] (from on the road) or moves
    further away from them (from off it)."""
    low, high = bounds
    if low <= y0 <= high:
        return bool(np.any((y < low - TOLERANCE) | (y > high + TOLERANCE)))
    distance = np.maximum(low - y, 0.0) + np.maximum(y - high, 0.0)
    return bool(np.any(np.diff(distance) > TOLERANCE))


def success_reversal(result, scene: Scene) -> tuple[float, float] | None:
    """(metres back from the furthest point reached, fastest speed [m/s] against the direction of travel) of a SUCCESS
    plan, both >= 0; None for other statuses."""
    if result.status != PlanStatus.SUCCESS:
        return None
    direction = -1.0 if np.float32(scene.ego.vx) < 0.0 else 1.0  # driveopt.problem.travel_direction
    along_x = direction * (np.asarray(result.trajectory.x, np.float64) - result.x_offset)
    back = float(np.max(np.maximum.accumulate(along_x) - along_x))
    return back, max(0.0, -float(np.min(direction * np.asarray(result.trajectory.vx))))


def reversal_limits(config: PlannerConfig) -> tuple[float, float]:
    """([m], [m/s]) the promise's bounds on a SUCCESS plan's motion against the direction of travel: the velocity
    residual (an L2 norm over the nodes) is within ``residual_tolerance``, so no node is faster against it than that,
    and all nodes together cover at most ``residual_tolerance * dt * sqrt(nodes)`` (Cauchy-Schwarz)."""
    speed = config.sampler.residual_tolerance
    return speed * config.basis.dt * math.sqrt(config.basis.num_nodes), speed


def is_reversal(back: float, speed: float, limits: tuple[float, float]) -> bool:
    return back > limits[0] + FLOAT_SLACK or speed > limits[1] + FLOAT_SLACK


def small_config(samples: int, iterations: int, projection_iterations: int) -> PlannerConfig:
    """The planner with ``samples`` per iteration, ``iterations`` sampler iterations and ``projection_iterations``; a
    third of the samples are constraint elites and an eighth elites (P1: 100 and 40 of 1000)."""
    sampler = {"num_samples": samples, "num_iterations": iterations, "num_constraint_elites": max(1, samples // 3),
               "num_elites": max(1, samples // 8)}
    return PlannerConfig().replace(sampler=sampler, projection={"max_iterations": projection_iterations})


class Tally:
    """Counts of one problem set."""

    def __init__(self) -> None:
        self.planned = 0
        self.status: Counter = Counter()
        self.fallback: Counter = Counter()
        self.fallback_problems = 0
        self.success_reversals = 0  # beyond the promise's tolerance
        self.success_noise = 0  # beyond float32 noise
        self.worst_back, self.worst_speed = 0.0, 0.0  # [m], [m/s] over SUCCESS plans
        self.examples: dict[str, list] = {}

    def add(self, index: int, scene: Scene, result, limits: tuple[float, float]) -> None:
        self.planned += 1
        self.status[result.status.name] += 1
        broken = fallback_violations(result, scene)
        self.fallback.update(broken)
        self.fallback_problems += bool(broken)
        reversal = success_reversal(result, scene)
        if reversal is not None:
            self.worst_back, self.worst_speed = max(self.worst_back, reversal[0]), max(self.worst_speed, reversal[1])
            self.success_noise += is_reversal(*reversal, (NOISE, NOISE))
            if is_reversal(*reversal, limits):
                self.success_reversals += 1
                broken = [*broken, "success_against_travel"]
        for name in broken:
            kept = self.examples.setdefault(name, [])
            if len(kept) < EXAMPLES:
                kept.append({"key": index, "problem": scene_to_dict(scene)})

    def report(self) -> dict:
        return {
            "planned": self.planned, "status": dict(self.status),
            "fallback_violations": {"problems": self.fallback_problems, "by_promise": dict(self.fallback)},
            "success_against_travel": self.success_reversals, "success_against_travel_beyond_noise": self.success_noise,
            "success_worst": {"back_m": self.worst_back, "speed_against_m_s": self.worst_speed},
            "examples": self.examples,
        }


def run(args, path: Path) -> int:
    config = small_config(args.samples, args.iterations, args.projection_iterations)
    limits = reversal_limits(config)
    rng = np.random.default_rng(args.seed)
    sets = [("random", args.random, random_scene), ("realistic", args.realistic, realistic_scene)]
    tallies = {name: Tally() for name, _, _ in sets}
    report = {"config": {"samples": args.samples, "iterations": args.iterations,
                         "projection_iterations": args.projection_iterations, "seed": args.seed},
              "tolerances": {"fallback": TOLERANCE, "reversal_distance_m": limits[0], "reversal_speed_m_s": limits[1],
                             "noise": NOISE, "float_slack": FLOAT_SLACK}}
    start, interrupted = time.perf_counter(), False
    bar = tqdm(total=args.random + args.realistic, desc="stop property", unit="problem")
    try:
        for name, count, draw in sets:
            for _ in range(count):
                scene, index = draw(rng), bar.n
                result = plan(build_problem(scene, config.basis), config, key=jax.random.PRNGKey(index), x_offset=scene.ego.x)
                tallies[name].add(index, scene, result, limits)
                bar.update()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
    report.update(interrupted=interrupted, elapsed_s=time.perf_counter() - start,
                  sets={name: tally.report() for name, tally in tallies.items()})
    write_json(path, report)
    for name, tally in tallies.items():
        print(f"{name:>9}: {tally.planned} planned ({dict(tally.status)}); fallback violations in "
              f"{tally.fallback_problems} ({dict(tally.fallback)}); SUCCESS plans against the direction of travel: "
              f"{tally.success_reversals} beyond the tolerance, {tally.success_noise} beyond noise (worst {tally.worst_back:.4f} m "
              f"back, {tally.worst_speed:.4f} m/s)")
    print(f"{'interrupted: ' if interrupted else ''}wrote {path}")
    return 130 if interrupted else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default="out/stop_property.json", help="results file")
    parser.add_argument("--random", type=int, default=5000, help="problems from the whole accepted range")
    parser.add_argument("--realistic", type=int, default=2000, help="highway-traffic problems")
    parser.add_argument("--samples", type=int, default=64, help="samples per sampler iteration")
    parser.add_argument("--iterations", type=int, default=2, help="sampler iterations")
    parser.add_argument("--projection-iterations", type=int, default=10, help="projection iterations")
    parser.add_argument("--seed", type=int, default=0, help="seed of the problems drawn")
    args = parser.parse_args(argv)
    if min(args.random, args.realistic, args.projection_iterations, args.seed) < 0 or min(args.samples, args.iterations) < 1:
        parser.error("--random, --realistic, --projection-iterations and --seed must be >= 0, --samples and "
                     "--iterations >= 1")
    path = Path(args.json)
    if path.is_dir():
        parser.error(f"--json {path} is a directory")
    return run(args, path)


if __name__ == "__main__":
    sys.exit(main())
