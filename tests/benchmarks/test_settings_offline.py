"""benchmarks/perf/settings_offline.py: lanes of set-points and how picks are compared."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.perf import settings_offline
from driveopt.problem import build_problem
from driveopt.scene import load_scene


def pick(lanes, speeds, status="SUCCESS"):
    return {"status": status, "lanes": lanes, "speeds": speeds, "residual": 0.0, "median_residual": 1.0,
            "min_residual": 0.0, "feasible_rows": 10, "ms": 5.0}


def test_lateral_set_points_map_to_the_nearest_lane_within_the_road():
    problem = build_problem(load_scene("slow-leader-four-lane"))
    centre, width = float(problem.lane_center0), float(problem.lane_width)
    lateral = np.array([centre - 3 * width, centre + 0.4 * width, centre + 1.6 * width, centre + 9 * width])
    assert settings_offline.lanes(problem, lateral) == [0, 0, 2, int(problem.num_lanes) - 1]


def test_agreement_against_the_own_pick():
    records = [{"own": pick([0, 0, 1, 1], [10, 10, 10, 10]), "changed": pick([0, 0, 1, 1], [10, 11, 10, 10])},
               {"own": pick([0, 0, 0, 0], [10, 10, 10, 10]), "changed": pick([0, 1, 1, 1], [10, 10, 13, 10])}]
    agreement = settings_offline.agreement(records, "changed")
    assert agreement["same_lanes"] == 0.5 and agreement["same_last_lane"] == 0.5
    assert agreement["speed_gap_median"] == pytest.approx(2.0)


def test_saved_states_load_as_the_same_problems(tmp_path):
    problems = [("a", build_problem(load_scene("slow-leader-four-lane"))), ("b", build_problem(load_scene("dense-snapshot")))]
    settings_offline.save_states(tmp_path / "s.npz", problems)
    loaded = settings_offline.load_states(tmp_path / "s.npz")
    assert [name for name, _ in loaded] == ["a", "b"]
    for (_, before), (_, after) in zip(problems, loaded):
        for field in before._fields:
            np.testing.assert_array_equal(np.asarray(getattr(after, field)), np.asarray(getattr(before, field)))
