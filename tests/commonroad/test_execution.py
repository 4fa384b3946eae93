"""The ``tracked`` execution model without CommonRoad's packages: driveopt's bicycle and tracker follow plans given in a
CommonRoad path frame; ``--execution`` takes only its models, FISS is not tracked, and an output folder holds one
model."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from driveopt.cli import main
from driveopt.commonroad import EXECUTIONS
from driveopt.commonroad.execution import Car, frame_state, step, vehicle_model
from driveopt.commonroad.path import PathFrame

# CommonRoad's VW_VANAGON (commonroad_dc's VehicleParameterMapping): axle distances a, b [m], a_max [m/s^2], steering [rad]
VANAGON = SimpleNamespace(a=1.1507916024, b=1.3211363976, longitudinal=SimpleNamespace(a_max=11.5),
                          steering=SimpleNamespace(min=-1.023, max=1.023))
MODEL = vehicle_model(VANAGON, 0.1)
LENGTH, WIDTH = 4.569, 1.844  # [m]
NODES = np.linspace(0.0, 15.0, 101)  # [s] the plan's nodes, as driveopt's basis (0.15 s apart)


def _plan(s, d, start: float):
    """A road-frame trajectory at ``NODES`` from time ``start`` [s] of the reference motion ``s(t)``, ``d(t)`` (each
    returning position, rate, second rate)."""
    t = start + NODES
    (x, vx, ax), (y, vy, ay) = s(t), d(t)
    return SimpleNamespace(t=NODES, x=x, y=y, vx=vx, vy=vy, ax=ax, ay=ay)


def _drive(frame: PathFrame, s, d, steps: int, speed: float) -> list[tuple[float, ...]]:
    """(time [s], car's station and offset [m], speed [m/s], distance [m] from the step's plan at its end) over ``steps`` time steps tracking the reference motion,
    the car starting on it at ``speed`` along the frame."""
    (s0, _, _), (d0, _, _) = s(np.array(0.0)), d(np.array(0.0))
    xy = frame.to_world(np.array(s0), np.array(d0))
    car = Car(float(xy[0]), float(xy[1]), float(frame.heading(np.array(s0))), speed, 0.0, 0.0)
    out = []
    for k in range(steps):
        car, deviation = step(car, _plan(s, d, 0.1 * k), frame, MODEL)
        ego = frame_state(car, frame, MODEL, LENGTH, WIDTH)
        out.append((0.1 * (k + 1), ego.x, ego.y, car.speed, deviation))
    return out


def test_the_model_is_the_vanagon_integrated_every_10_ms():
    assert MODEL.length == pytest.approx(2.472, abs=1e-3)  # the wheelbase a + b
    assert MODEL.simulation_dt == pytest.approx(0.01) and MODEL.steps_per_action == 10
    assert MODEL.acceleration_range == (-11.5, 11.5) and MODEL.steering_range == (-1.023, 1.023)
    with pytest.raises(ValueError, match="whole multiple"):
        vehicle_model(VANAGON, 0.105)


def test_a_constant_speed_straight_plan_is_followed_within_a_millimetre():
    """On a straight road, 15 m/s in a lane 1.75 m left of the reference line, for 5 s (50 steps, each a new plan of
    the same motion): the car stays within 1 mm of the plan and within 1e-6 m/s of its speed (tolerances)."""
    frame = PathFrame(np.array([[0.0, 0.0], [600.0, 0.0]]))
    s = lambda t: (10.0 + 15.0 * t, np.full_like(t, 15.0), np.zeros_like(t))  # noqa: E731
    d = lambda t: (np.full_like(t, 1.75), np.zeros_like(t), np.zeros_like(t))  # noqa: E731
    for time, station, offset, speed, deviation in _drive(frame, s, d, 50, 15.0):
        assert abs(station - (10.0 + 15.0 * time)) < 1e-3 and abs(offset - 1.75) < 1e-3 and deviation < 1e-3
        assert speed == pytest.approx(15.0, abs=1e-6)


def test_a_straight_plan_on_a_turned_road_is_followed_too():
    """The same plan on a road along 30 degrees: the world axes are the frame's turned, nothing else."""
    angle = math.radians(30.0)
    frame = PathFrame(np.array([[0.0, 0.0], [600.0 * math.cos(angle), 600.0 * math.sin(angle)]]))
    s = lambda t: (10.0 + 15.0 * t, np.full_like(t, 15.0), np.zeros_like(t))  # noqa: E731
    d = lambda t: (np.full_like(t, -1.75), np.zeros_like(t), np.zeros_like(t))  # noqa: E731
    for time, station, offset, speed, deviation in _drive(frame, s, d, 50, 15.0):
        assert abs(station - (10.0 + 15.0 * time)) < 1e-3 and abs(offset + 1.75) < 1e-3 and deviation < 1e-3
        assert speed == pytest.approx(15.0, abs=1e-6)


def test_a_lane_change_while_accelerating_is_followed_within_5_cm():
    """3.5 m to the left over 4 s (a quintic) while speeding up from 10 m/s at 1 m/s^2: within 5 cm across, 5 cm
    along and 0.01 m/s of the plan at every step (the exact inverse holds the course, not the position)."""
    frame = PathFrame(np.array([[0.0, 0.0], [600.0, 0.0]]))

    def s(t):
        return 10.0 + 10.0 * t + 0.5 * t * t, 10.0 + t, np.ones_like(t)

    def d(t):
        u = np.clip(t / 4.0, 0.0, 1.0)
        inside = (t > 0.0) & (t < 4.0)
        return (3.5 * (10 * u**3 - 15 * u**4 + 6 * u**5), inside * 3.5 * (30 * u**2 - 60 * u**3 + 30 * u**4) / 4.0,
                inside * 3.5 * (60 * u - 180 * u**2 + 120 * u**3) / 16.0)

    for time, station, offset, speed, deviation in _drive(frame, s, d, 60, 10.0):
        (s_ref, v_s, _), (d_ref, v_d, _) = s(np.array(time)), d(np.array(time))
        assert abs(station - s_ref) < 0.05 and abs(offset - d_ref) < 0.05, (time, station - s_ref, offset - d_ref)
        # the plan read between its nodes (cubic Hermite) is the reference motion to 0.1 mm
        assert deviation == pytest.approx(math.hypot(station - s_ref, offset - d_ref), abs=1e-4)
        assert speed == pytest.approx(math.hypot(v_s, v_d), abs=0.01)


def test_a_bad_execution_is_one_line_and_status_2(tmp_path, capsys):
    (tmp_path / "s.xml").write_text("<commonRoad/>")
    with pytest.raises(SystemExit) as info:
        main(["commonroad", "--scenarios", str(tmp_path), "--execution", "exact", "--out", str(tmp_path / "out")])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("driveopt: error:") and "'exact'" in err and "\n" not in err
    assert EXECUTIONS == ("perfect", "tracked")


def test_fiss_is_not_tracked(tmp_path, capsys):
    (tmp_path / "s.xml").write_text("<commonRoad/>")
    assert main(["commonroad", "--scenarios", str(tmp_path), "--planners", "bilevel", "fiss_plus", "--execution",
                 "tracked", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "fiss_plus run in FISS's own closed loop" in err and "\n" not in err
    assert not (tmp_path / "out" / "runs.jsonl").exists()


@pytest.mark.parametrize("held, asked", [("perfect", "tracked"), ("tracked", "perfect"), (None, "tracked")])
def test_a_folder_refuses_a_second_execution_model(tmp_path, capsys, held, asked):
    """A folder's records name their model (one without it is ``perfect``'s); another model is refused before
    anything runs, the records kept."""
    (tmp_path / "s.xml").write_text("<commonRoad/>")
    out = tmp_path / "out"
    out.mkdir()
    record = {"scenario": "s", "planner": "bilevel", "status": "timeout", "goal_reached": False}
    if held is not None:
        record["execution"] = held
    text = json.dumps(record) + "\n"
    (out / "runs.jsonl").write_text(text)
    assert main(["commonroad", "--scenarios", str(tmp_path), "--planners", "bilevel", "--execution", asked,
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"holds runs with --execution {held or 'perfect'}" in err and "one execution model" in err and "\n" not in err
    assert (out / "runs.jsonl").read_text() == text


def test_the_summary_names_the_execution_model():
    from driveopt.commonroad.bench import summary_table

    record = {"scenario": "s", "planner": "bilevel", "execution": "tracked", "status": "success", "arrival_step": 30,
              "plan_ms_median": 50.0, "plan_ms_p95": 60.0}
    table = summary_table([record])
    assert "| bilevel | tracked | 1 | 1 |" in table and "| s | bilevel | tracked | success | 30 |" in table
