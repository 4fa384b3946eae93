"""Scenario registry: the closed-loop test cases, as frozen, unit-annotated dataclasses.

Naming scheme (``list_scenarios()`` prints them all)::

    two-lane-d1.0 ... two-lane-d3.0      straight 2-lane highway (highway-env ``highway-v0`` layout)
    four-lane-d1.0 ... four-lane-d3.0    straight 4-lane highway
    three-lane-d*, five-lane-d*          the same with 3 and 5 lanes (the papers use 2 and 4)
    <any of the above>-slow              the same with a 7 m/s neighbour speed limit (P2) instead of 15 m/s
    p2-four-lane-d1.0 ... -d3.0[-slow]   P2's traffic (Fig. 7): 4 lanes, neighbour target speeds ~ U(0, limit)
    two-way                              ``two-way-v0``: overtaking on a lane shared with oncoming traffic (P1)
    merge                                ``merge-v0``: 2-lane highway with vehicles merging from an on-ramp

``d<density>`` is highway-env's ``vehicles_density`` in {1.0, 1.5, 2.0, 2.5, 3.0}: neighbours spawn
ahead of the ego with gaps proportional to ``1 / density``.

Neighbours' IDM target speeds are drawn uniformly in ``target_speed_fraction * speed_limit``: P1's
traffic (and driveopt's defaults) use (0.7, 0.8); P2 lets every neighbour choose its speed between zero
and the limit (P2 Fig. 7 caption), the ``p2-*`` scenarios: ``p2-four-lane-d3.0`` (density 3, 15 m/s,
P2 Fig. 8's setting) and ``p2-four-lane-d1.5-slow`` (density 1.5, 7 m/s) among them. P2's text does not
name its lane count; driveopt's P2 variants use four lanes, the road of P1's dense benchmark and of the
shipped four-lane weights. Any scenario takes P2's traffic with ``--scenario-config`` and
``{"target_speed_fraction": [0.0, 1.0]}``.

Every field can be overridden from a mapping or a JSON object file::

    scenario = resolve_scenario("four-lane-d3.0", config_file="my.json", overrides={"duration": 20.0})

Unknown keys and values of the wrong type or beyond their range (``MAX_VEHICLES``, ``MAX_DURATION``,
``MAX_SIMULATION_FREQUENCY``, ...) raise :class:`ScenarioError` naming the field; so does an episode whose
simulation work (duration x simulation_frequency x cars) exceeds ``MAX_VEHICLE_STEPS``, unless the
environment variable ``DRIVEOPT_ALLOW_LARGE=1`` is set. Override files are read by
:func:`driveopt.jsonfile.read_json`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from driveopt.checks import ConfigError, check_budget
from driveopt.config import MAX_ACCELERATION, MAX_SPEED
from driveopt.errors import DriveoptError
from driveopt.gym_envs import ROAD_ENVS
from driveopt.jsonfile import read_json

ROADS = tuple(ROAD_ENVS)
"""Road layouts, each an upstream highway-env environment: highway-v0, two-way-v0, merge-v0 (the layouts of
:data:`driveopt.gym_envs.ROAD_ENVS`, which registers an adapter env for each)."""

DENSITIES = (1.0, 1.5, 2.0, 2.5, 3.0)
"""[-] highway-env ``vehicles_density`` values of the registered highway scenarios (P1, P2)."""

DEFAULT_SPEED_LIMIT = 15.0  # [m/s] neighbour speed limit of P1
SLOW_SPEED_LIMIT = 7.0  # [m/s] P2's slow-traffic variant
P1_TARGET_SPEEDS = (0.7, 0.8)  # [-] neighbour target speed ~ U(lo, hi) * speed_limit (P1's modified highway-env)
P2_TARGET_SPEEDS = (0.0, 1.0)  # [-] P2 Fig. 7: each neighbour chooses its speed uniformly between zero and the limit
P2_LANES = 4  # [-] lanes of the p2-* scenarios (P2's text does not say; P1's dense road)


# Ranges beyond which a scenario is degenerate or cannot run: highway-env allocates per simulation step of an action
# (1e9 Hz: gigabytes), spawns and steps its traffic in time growing with the car count (1e5 cars: hours for a reset),
# and an acceleration of 1e300 m/s^2 gives an infinite, then NaN, state.
MAX_LANES = 16  # [-] lanes of a highway road
MIN_DENSITY, MAX_DENSITY = 0.1, 10.0  # [-] vehicles_density (spawn gaps scale with 1 / density; registered: 1 to 3)
MAX_VEHICLES = 1000  # [-] neighbours spawned on a highway
MAX_GAP = 1000.0  # [m] min_initial_gap and min_spawn_gap
MAX_DURATION = 3600.0  # [s] episode length (P1: 50 s)
MAX_SIMULATION_FREQUENCY = 1000  # [Hz] highway-env integration rate (default 20)
MAX_VEHICLE_STEPS = 1e6  # [-] duration x simulation_frequency x (vehicles_count + 1): the simulation work of an
# episode, 20 times the default episode's (5.1e4); DRIVEOPT_ALLOW_LARGE=1 lifts it (driveopt.checks.check_budget)
SECONDS_PER_VEHICLE_STEP = 3e-3  # [s] measured on 2 busy CPU cores (highway-env's IDM traffic, 50 to 200 cars)


class ScenarioError(DriveoptError):
    """Unknown scenario name, unknown field, or a field value of the wrong type or range."""


@dataclass(frozen=True)
class Scenario:
    """One closed-loop test case: road layout, traffic, ego start, timing.

    ``density`` and ``vehicles_count`` are used by the ``highway`` road only; ``two-way`` and
    ``merge`` place their few neighbours where upstream highway-env does. On every road the
    neighbours' IDM target speed is drawn uniformly in ``target_speed_fraction * speed_limit``
    at reset from the env's generator (seeded by ``env.reset(seed=...)``; their initial speed is set
    to it), and the limit is written on every lane. Fractions lie in [0, 1]: upstream's IDM clips a
    target speed to the lane's limit, so a fraction above 1 would only start a car over the limit.
    """

    name: str
    road: str = "highway"  # layout, one of ROADS
    lanes: int = 4  # [-] lanes in the direction of travel (two-way and merge: 2, fixed upstream)
    density: float = 1.0  # [-] highway-env vehicles_density (highway only): spawn gaps scale with 1 / density
    vehicles_count: int = 50  # [-] neighbours spawned (highway only)
    speed_limit: float = DEFAULT_SPEED_LIMIT  # [m/s] neighbours' road speed limit
    target_speed_fraction: tuple[float, float] = P1_TARGET_SPEEDS  # [-] neighbour target speed [m/s] ~ U(lo, hi) * speed_limit
    traffic_reverses: bool = False  # True: upstream's IDM cars, which may roll backwards (to -40 m/s); False: they stop at 0 m/s
    ego_speed: float = 10.0  # [m/s] ego speed at reset (a slow ego behind the traffic, as in P1)
    min_initial_gap: float = 10.0  # [m] highway: every neighbour spawns at least this far ahead of the ego centre
    min_spawn_gap: float = 5.0  # [m] highway: bumper gap between same-lane vehicles at reset (upstream overlaps cars)
    duration: float = 50.0  # [s] episode length (P1: 50 s)
    simulation_frequency: int = 20  # [Hz] highway-env integration rate
    policy_frequency: int = 10  # [Hz] ego actions per second (= replanning rate); divides simulation_frequency
    v_des: float = 20.0  # [m/s] ego desired speed
    acceleration_range: tuple[float, float] = (-5.0, 5.0)  # [m/s^2] ContinuousAction action[0] in [-1, 1] maps here
    steering_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)  # [rad] action[1] in [-1, 1] maps here
    description: str = ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _coerce(f.name, getattr(self, f.name), _FIELD_TYPES[f.name]))
        self._check_road_and_traffic()
        check_duration(self.duration)
        self._check_timing()
        self._check_ego()

    def _check_road_and_traffic(self) -> None:
        _check(self.road in ROADS, f"road must be one of {list(ROADS)}, got {self.road!r}")
        _check(1 <= self.lanes <= MAX_LANES, f"lanes must be in [1, {MAX_LANES}], got {self.lanes}")
        if self.road != "highway":
            _check(self.lanes == 2, f"road {self.road!r} has 2 lanes upstream; lanes must be 2, got {self.lanes}")
        _in_range("density", self.density, MIN_DENSITY, MAX_DENSITY, "")
        _check(0 <= self.vehicles_count <= MAX_VEHICLES, f"vehicles_count must be in [0, {MAX_VEHICLES}], "
               f"got {self.vehicles_count}")
        _in_range("speed_limit", self.speed_limit, 0.0, MAX_SPEED, "m/s", low_open=True)
        lo, hi = self.target_speed_fraction
        _check(0 <= lo <= hi <= 1, "target_speed_fraction must be (lo, hi) with 0 <= lo <= hi <= 1 [-] (fractions of "
               f"speed_limit: neighbour target speeds ~ U(lo, hi) * speed_limit), got {self.target_speed_fraction}")
        _in_range("min_initial_gap", self.min_initial_gap, 0.0, MAX_GAP, "m")
        _in_range("min_spawn_gap", self.min_spawn_gap, 0.0, MAX_GAP, "m")

    def _check_ego(self) -> None:
        _in_range("ego_speed", self.ego_speed, 0.0, MAX_SPEED, "m/s")
        _in_range("v_des", self.v_des, 0.0, MAX_SPEED, "m/s")
        a_lo, a_hi = self.acceleration_range
        _check(-MAX_ACCELERATION <= a_lo < 0 < a_hi <= MAX_ACCELERATION, "acceleration_range must be (lo, hi) with "
               f"-{MAX_ACCELERATION:g} <= lo < 0 < hi <= {MAX_ACCELERATION:g} [m/s^2], got {self.acceleration_range}")
        s_lo, s_hi = self.steering_range
        _check(-math.pi / 2 < s_lo < 0 < s_hi < math.pi / 2, "steering_range must satisfy -pi/2 < lo < 0 < hi < pi/2 [rad]")

    def _check_timing(self) -> None:
        """Frequencies in range and in step, at least one action, and the episode's simulation work within
        MAX_VEHICLE_STEPS (unless DRIVEOPT_ALLOW_LARGE=1)."""
        _check(1 <= self.simulation_frequency <= MAX_SIMULATION_FREQUENCY and 1 <= self.policy_frequency,
               f"frequencies must be integers in [1, {MAX_SIMULATION_FREQUENCY}] Hz, got simulation_frequency "
               f"{self.simulation_frequency} and policy_frequency {self.policy_frequency}")
        _check(
            self.simulation_frequency % self.policy_frequency == 0,
            f"simulation_frequency ({self.simulation_frequency} Hz) must be a multiple of policy_frequency "
            f"({self.policy_frequency} Hz): highway-env holds each action for simulation_frequency // "
            "policy_frequency steps but advances its clock by 1 / policy_frequency, so a remainder desynchronises them",
        )
        _check(self.num_actions >= 1, f"duration ({self.duration:g} s) must last at least one action "
               f"(1 / policy_frequency = {1 / self.policy_frequency:g} s)")
        steps = self.duration * self.simulation_frequency * (self.vehicles_count + 1)
        try:
            check_budget("simulation work per episode (duration x simulation_frequency x vehicles)", steps,
                         MAX_VEHICLE_STEPS, f"about {steps * SECONDS_PER_VEHICLE_STEP / 3600:.2g} hours on 2 CPU cores")
        except ConfigError as exc:
            raise ScenarioError(str(exc)) from None

    @property
    def steps_per_action(self) -> int:
        """[-] simulation steps that one action is held for."""
        return self.simulation_frequency // self.policy_frequency

    @property
    def num_actions(self) -> int:
        """[-] actions (replanning calls) in a full-length episode."""
        return round(self.duration * self.policy_frequency)

    @property
    def target_speed_range(self) -> tuple[float, float]:
        """[m/s] range of the neighbours' target speeds."""
        return self.target_speed_fraction[0] * self.speed_limit, self.target_speed_fraction[1] * self.speed_limit

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (validated like an override file)."""
        return apply_overrides(self, changes)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of every field (tuples as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


_FIELD_TYPES: dict[str, Any] = typing.get_type_hints(Scenario)


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise ScenarioError(message)


def _in_range(name: str, value: float, low: float, high: float, unit: str, low_open: bool = False) -> None:
    inside = (low < value if low_open else low <= value) and value <= high
    _check(inside, f"{name} must be in {'(' if low_open else '['}{low:g}, {high:g}]{' ' + unit if unit else ''}, "
                   f"got {value:g}")


def check_duration(duration: Any) -> float:
    """``duration`` [s] as a float; ScenarioError unless it is a finite number in (0, MAX_DURATION] (the
    command line's ``--duration`` and the experiment options use it, as the scenarios do)."""
    _check(_is_number(duration) and math.isfinite(duration), f"duration must be a finite number, got {duration!r}")
    _in_range("duration", duration, 0.0, MAX_DURATION, "s", low_open=True)
    return float(duration)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _coerce(name: str, value: Any, hint: Any) -> Any:
    """Check ``value`` against the field's annotation; return it in canonical form (float, tuple)."""
    if hint is str:
        _check(isinstance(value, str), f"{name} must be a string, got {value!r}")
        return value
    if hint is bool:
        _check(isinstance(value, bool), f"{name} must be true or false, got {value!r}")
        return value
    if hint is int:
        _check(isinstance(value, int) and not isinstance(value, bool), f"{name} must be an integer, got {value!r}")
        return value
    if hint is float:
        _check(_is_number(value) and math.isfinite(value), f"{name} must be a finite number, got {value!r}")
        return float(value)
    if typing.get_origin(hint) is tuple:
        size = len(typing.get_args(hint))
        ok = isinstance(value, (list, tuple)) and len(value) == size and all(
            _is_number(v) and math.isfinite(v) for v in value
        )
        _check(ok, f"{name} must be a list of {size} finite numbers, got {value!r}")
        return tuple(float(v) for v in value)
    raise TypeError(f"no coercion rule for field {name}: {hint!r}")  # a new field type needs a rule here


def apply_overrides(scenario: Scenario, overrides: Mapping[str, Any]) -> Scenario:
    """``scenario`` with the fields in ``overrides`` replaced; unknown keys or bad values raise ScenarioError."""
    if not isinstance(overrides, Mapping):
        raise ScenarioError(f"scenario overrides must be a mapping of field -> value, got {type(overrides).__name__}")
    valid = [f.name for f in dataclasses.fields(Scenario)]
    unknown = sorted(set(overrides) - set(valid))
    if unknown:
        raise ScenarioError(f"unknown scenario field(s) {unknown}; valid fields: {valid}")
    return dataclasses.replace(scenario, **dict(overrides))


def load_overrides(path: str | Path) -> dict[str, Any]:
    """Read a JSON object of scenario field overrides from ``path`` (through :func:`driveopt.jsonfile.read_json`:
    special files, huge files, deep nesting, huge numbers and invalid Unicode are refused)."""
    data = read_json(path, "scenario config file", ScenarioError)
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: must hold a JSON object of scenario fields, got {type(data).__name__}")
    return data


def _highway(lanes: int, density: float, slow: bool) -> Scenario:
    word = {2: "two", 3: "three", 4: "four", 5: "five"}[lanes]
    limit = SLOW_SPEED_LIMIT if slow else DEFAULT_SPEED_LIMIT
    return Scenario(
        name=f"{word}-lane-d{density:.1f}" + ("-slow" if slow else ""),
        road="highway",
        lanes=lanes,
        density=density,
        speed_limit=limit,
        # a slow ego behind the traffic: just below the neighbours' slowest target speed
        ego_speed=10.0 if not slow else 5.0,
        description=f"{lanes}-lane straight highway, density {density:.1f}, neighbours under {limit:g} m/s",
    )


def _p2_highway(density: float, slow: bool) -> Scenario:
    """P2's traffic (Fig. 7): neighbours choose their target speed uniformly between zero and the limit."""
    base = _highway(P2_LANES, density, slow)
    return dataclasses.replace(
        base,
        name=f"p2-{base.name}",
        target_speed_fraction=P2_TARGET_SPEEDS,
        description=f"{P2_LANES}-lane straight highway, density {density:.1f}, neighbour target speeds uniform in "
                    f"[0, {base.speed_limit:g}] m/s (P2 Fig. 7)",
    )


def _registry() -> dict[str, Scenario]:
    scenarios = [_highway(lanes, d, slow) for slow in (False, True) for lanes in (2, 4) for d in DENSITIES]
    # other lane counts (P1 and P2 use 2 and 4): the planner must not depend on them
    scenarios += [_highway(lanes, d, False) for lanes in (3, 5) for d in DENSITIES]
    scenarios += [_p2_highway(d, slow) for slow in (False, True) for d in DENSITIES]
    scenarios.append(
        Scenario(
            name="two-way",
            road="two-way",
            lanes=2,
            vehicles_count=5,
            ego_speed=15.0,
            duration=30.0,  # upstream road is 800 m long: 30 s at v_des stays on it
            description="two-way-v0: overtake 3 slow vehicles on a lane shared with 2 oncoming ones (P1)",
        )
    )
    scenarios.append(
        Scenario(
            name="merge",
            road="merge",
            lanes=2,
            vehicles_count=4,
            ego_speed=15.0,
            duration=30.0,  # upstream ends the episode once the ego passes x = 370 m
            description="merge-v0: 2-lane highway, vehicles joining from an on-ramp on the right",
        )
    )
    return {s.name: s for s in scenarios}


SCENARIOS: Mapping[str, Scenario] = _registry()


def list_scenarios() -> list[str]:
    """Names of every registered scenario, in registry order."""
    return list(SCENARIOS)


def get_scenario(name: str) -> Scenario:
    """The registered scenario ``name``; an unknown name raises ScenarioError listing the valid ones."""
    if name in SCENARIOS:
        return SCENARIOS[name]
    close = difflib.get_close_matches(str(name), SCENARIOS, n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise ScenarioError(f"unknown scenario {name!r}{hint}; valid scenarios: {', '.join(SCENARIOS)}")


def resolve_scenario(
    name: str, *, config_file: str | Path | None = None, overrides: Mapping[str, Any] | None = None
) -> Scenario:
    """Registered scenario ``name``, then the fields of ``config_file`` (JSON), then ``overrides``."""
    scenario = get_scenario(name)
    if config_file is not None:
        scenario = apply_overrides(scenario, load_overrides(config_file))
    if overrides:
        scenario = apply_overrides(scenario, overrides)
    return scenario
