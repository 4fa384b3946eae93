"""Closed loop: every scenario with every planner, determinism, the drive and bench commands."""

import json

import numpy as np
import pytest

from driveopt.cli import main
from driveopt.drivers.rl import RLSpec
from driveopt.experiments.rollout import Rollout, run_episode
from driveopt.registry import get_planner, list_planners
from driveopt.rl.policy import PolicyError, shipped_policy
from driveopt.sim.road_frame import RoadFrameError
from driveopt.sim.scenarios import get_scenario, list_scenarios


def small(name):
    spec = get_planner(name)
    if name in ("bilevel", "random", "cvae", "cvae-mix", "vqvae", "vqvae-cem", "vqvae-filter"):
        spec = spec.with_overrides(sampler={"num_samples": 40, "num_constraint_elites": 20, "num_elites": 10},
                                   projection={"max_iterations": 5})
    elif name.endswith("-faithful"):  # the authors' budgets (1000 samples, up to 100 iterations): a test needs less
        spec = spec.with_samples(40).with_overrides(projection={"max_iterations": 5})
    return spec


REPRESENTATIVE = ("two-lane-d1.0", "three-lane-d2.0", "four-lane-d3.0", "five-lane-d2.5", "two-way", "merge")


def _runs(planner, scenario):
    spec = small(planner)
    if isinstance(spec, RLSpec) and shipped_policy(spec.algo, get_scenario(scenario).lanes) is None:
        # no policy shipped for this road (yet): the error names the command that trains one (tests/test_rl.py drives them)
        with pytest.raises(PolicyError, match=f"driveopt train {spec.algo} --scenario {scenario}"):
            run_episode(scenario, spec, seed=1, duration=0.3)
        return
    episode = run_episode(scenario, spec, seed=1, duration=0.3)
    assert len(episode.speeds) >= 1 and np.all(np.isfinite(episode.speeds))
    assert episode.sim_duration > 0
    if spec.is_optimiser:  # one plan every replan_every steps (the -p1 baselines: 5)
        plans = -(-len(episode.speeds) // spec.loop.replan_every)
        assert sum(episode.statuses.values()) == plans == len(episode.plan_ms)
        assert episode.compile_seconds > 0


VARIANTS = ("-p1", "-faithful", "vqvae-cem", "cvae-filter", "vqvae-filter")  # the same code as a base planner with other settings: one road is enough
EVERY_LAYOUT = ("bilevel", "grid", "idm")  # the other planners share their road handling: the extreme lane counts suffice


SLOW_IN_DEFAULT_RUN = ("vqvae-filter",)  # 26 s on a fresh clone; tests/training/test_filter.py plans with it
FAITHFUL_IN_DEFAULT_RUN = ("vanilla-faithful",)  # one faithful planner: the others share its driver settings, and
# tests/core/test_registry.py plans with their priors


def _planner_cases():
    for name in list_planners():
        slow = (name.endswith("-faithful") and name not in FAITHFUL_IN_DEFAULT_RUN) or name in SLOW_IN_DEFAULT_RUN
        yield pytest.param(name, marks=pytest.mark.slow) if slow else name


@pytest.mark.parametrize("planner", list(_planner_cases()))
def test_every_planner_runs_on_every_road_layout_and_lane_count(planner):
    if planner.endswith(VARIANTS):
        roads = ("four-lane-d3.0",)
    elif planner in EVERY_LAYOUT:
        roads = REPRESENTATIVE
    else:
        roads = ("two-lane-d1.0", "five-lane-d2.5")
    for scenario in roads:
        _runs(planner, scenario)


def test_every_scenario_runs():
    assert {"three-lane-d1.0", "five-lane-d3.0"} <= set(list_scenarios())
    for scenario in list_scenarios():
        _runs("grid", scenario)


def test_same_seed_same_episode():
    a = run_episode("two-lane-d2.0", small("bilevel"), seed=7, duration=1.0)
    b = run_episode("two-lane-d2.0", small("bilevel"), seed=7, duration=1.0)
    assert a.speeds == b.speeds and a.lateral == b.lateral
    c = run_episode("two-lane-d2.0", small("bilevel"), seed=8, duration=1.0)
    assert a.speeds != c.speeds
    # Compilation (seconds) happens before the timed steps (milliseconds).
    assert get_planner("bilevel").warm_start and max(a.plan_ms) < 10 * float(np.median(a.plan_ms))


@pytest.mark.parametrize("planner", ["bilevel", "vqvae"])
def test_a_closed_loop_compiles_its_planner_once(planner, solve_graphs):
    """The first call (no warm start, no previous plan: their placeholders) and the later ones (both carried) run
    one graph, so one compilation; bilevel carries both, vqvae the previous plan. The configuration is the one
    test_every_planner_runs_... drives (one compilation for both tests)."""
    spec = small(planner)
    assert spec.config.cost.consistency > 0
    episode = run_episode("two-lane-d1.0", spec, seed=4, duration=1.0)
    assert sum(episode.statuses.values()) == 10
    assert len(solve_graphs) == 11 and len(set(solve_graphs)) == 1  # the driver's warm-up call and the 10 plans


def test_drive_command_writes_a_summary(tmp_path, capsys):
    out = tmp_path / "drive.json"
    assert main(["drive", "--scenario", "two-lane-d1.0", "--planner", "grid", "--duration", "0.5", "--video", "", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["scenario"] == "two-lane-d1.0" and summary["planner"] == "grid"
    assert {"collided", "off_road", "mean_speed", "plan_ms_median", "plan_ms_p95"} <= set(summary)


def test_drive_and_bench_reject_unknown_names(capsys):
    assert main(["drive", "--scenario", "six-lane"]) == 2
    assert "valid scenarios" in capsys.readouterr().err
    assert main(["bench", "--planners", "mpc-magic"]) == 2
    assert "valid planners" in capsys.readouterr().err


def test_bench_command_runs_real_episodes_and_resumes(tmp_path, capsys):
    args = ["bench", "--scenarios", "two-lane-d1.0", "--planners", "idm", "grid", "--episodes", "2",
            "--duration", "0.3", "--workers", "1", "--out", str(tmp_path)]
    assert main(args) == 0
    lines = (tmp_path / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 4
    assert main(args) == 0  # nothing left to do: no duplicates
    assert (tmp_path / "episodes.jsonl").read_text().splitlines() == lines
    assert "| two-lane-d1.0 | idm |" in (tmp_path / "summary.md").read_text()


def test_bench_config_overrides_reach_every_optimiser_and_fix_the_folder(tmp_path, capsys):
    slow = tmp_path / "slow.json"
    slow.write_text(json.dumps({"projection": {"v_max": 2.0}}))  # [m/s]: every plan must brake hard
    base = ["bench", "--scenarios", "two-lane-d1.0", "--planners", "grid", "--episodes", "1", "--duration", "0.5",
            "--workers", "1"]
    assert main(base + ["--out", str(tmp_path / "a")]) == 0
    assert main(base + ["--out", str(tmp_path / "b"), "--config", str(slow)]) == 0
    speed = {d: json.loads((tmp_path / d / "episodes.jsonl").read_text())["mean_speed"] for d in "ab"}
    assert speed["b"] < speed["a"] - 0.5
    assert main(base + ["--out", str(tmp_path / "a"), "--config", str(slow)]) == 2  # would mix two settings
    assert "other output folder" in capsys.readouterr().err
    slow.write_text(json.dumps({"cost": {"consistence": 1.0}}))
    assert main(base + ["--out", str(tmp_path / "c"), "--config", str(slow)]) == 2
    assert "consistency" in capsys.readouterr().err  # the valid keys are listed


def test_each_step_shows_the_state_the_plan_starts_from():
    """Videos draw at each yielded step: the executed plan must start at the ego's current position there."""
    gaps = []
    rollout = Rollout("four-lane-d1.0", small("grid").driver(), seed=2, duration=1.0)
    for step in rollout:
        ego = step.env.unwrapped.vehicle
        traj = step.decision.result.safe_trajectory
        gaps.append(float(np.hypot(traj.x[0] - ego.position[0], traj.y[0] - ego.position[1])))
        assert len(step.episode.speeds) == len(gaps) - 1  # the simulator has not advanced yet
    assert len(gaps) == 10 and max(gaps) < 0.05
    assert len(rollout.episode.speeds) == 10


def test_a_rollout_stopped_early_keeps_what_it_recorded():
    rollout = Rollout("two-lane-d1.0", get_planner("idm").driver(), seed=3, duration=5.0)
    for number, step in enumerate(rollout, start=1):
        if number == 4:
            break
    assert len(rollout.episode.speeds) == 3 and not rollout.episode.plan_ms


@pytest.mark.parametrize("planner", ["grid", "bilevel"])
def test_the_loop_carries_the_executed_plan_when_consistency_is_weighed(planner):
    """Each call after the first compares its samples with the previous call's executed plan, shifted by
    the replan period; compilation of that trace happens before the timed steps."""
    spec = small(planner).with_overrides(cost={"consistency": 1.0})
    rollout = Rollout("four-lane-d1.0", spec.driver(), seed=2, duration=1.0)
    results = [step.decision.result for step in rollout]
    episode = rollout.episode
    assert len(results) == 10
    assert results[0].costs["consistency"] == 0.0
    carried = [r.costs["consistency"] for r in results[1:]]
    assert all(np.isfinite(carried)) and max(carried) > 0.0
    assert max(episode.plan_ms) < 10 * float(np.median(episode.plan_ms))



class _StartOffRoad:
    """Wraps a driver: puts the ego ``beyond`` [m] outside the upper lane bound before the episode starts."""

    def __init__(self, driver, beyond):
        self.driver, self.beyond = driver, beyond
        self.name = driver.name

    def reset(self, env, scenario, seed):
        ego = env.unwrapped.vehicle
        lanes = scenario.lanes
        ego.position[1] = 4.0 * (lanes - 1) + 2.0 + self.beyond  # upstream lane centres at 0, 4, ...; edge 2 m out
        ego.heading = 0.0
        self.driver.reset(env, scenario, seed)
        self.compile_seconds = self.driver.compile_seconds

    def act(self, env):
        return self.driver.act(env)


@pytest.mark.parametrize("traffic", [True, False], ids=["traffic", "empty-road"])
def test_a_car_started_off_the_road_drives_back_onto_it(traffic):
    """Off-road recovery on three-lane-d1.0: from 1 m beyond the road's edge the bi-level planner is back within
    the lane bounds from 4 s on (recovery time 3 s) without a collision. On an empty road every plan back onto
    the road counts as feasible; in traffic some steps near other cars may not be (the small batch), so there
    only the recovery and the absence of collisions are asserted."""
    scenario = get_scenario("three-lane-d1.0")
    if not traffic:
        scenario = scenario.replace(vehicles_count=0)
    spec = small("bilevel")
    rollout = Rollout(scenario, _StartOffRoad(spec.driver(), beyond=1.0), seed=3, duration=6.0)
    bounds = []
    for step in rollout:
        if step.decision.scene is not None:
            bounds.append(step.decision.scene.lateral_bounds)
    episode = rollout.episode
    assert not episode.collided
    lo, hi = bounds[0]
    assert episode.lateral[0] > hi + 0.5  # it did start off the road
    after = np.asarray(episode.lateral[40:])  # from 4 s on (10 steps per second)
    assert np.all((after >= lo) & (after <= hi)), f"still off the road: y in [{after.min():.2f}, {after.max():.2f}], bounds [{lo}, {hi}]"
    if not traffic:
        assert episode.statuses == {"SUCCESS": len(episode.lateral)}, episode.statuses


class _PushedOffRoad:
    """Wraps a driver: after its ``at``-th action puts the ego 12 m beyond the upper lane edge, further than the
    road frame reaches (MAX_EGO_OFFSET, 8 m)."""

    def __init__(self, driver, at):
        self.driver, self.at, self.steps = driver, at, 0
        self.name = driver.name

    def reset(self, env, scenario, seed):
        self.driver.reset(env, scenario, seed)
        self.compile_seconds = self.driver.compile_seconds
        self.lanes = scenario.lanes

    def act(self, env):
        decision = self.driver.act(env)
        self.steps += 1
        if self.steps == self.at:
            env.unwrapped.vehicle.position[1] = 4.0 * (self.lanes - 1) + 2.0 + 12.0
        return decision


def test_an_episode_ends_off_road_when_the_car_leaves_the_frame_and_fails_when_it_starts_there():
    scenario = get_scenario("two-lane-d1.0").replace(vehicles_count=0)
    rollout = Rollout(scenario, _PushedOffRoad(small("grid").driver(), at=3), seed=3, duration=2.0)
    episode = rollout.run()  # the fourth call finds the ego off its frame: the episode ends there, off-road
    assert episode.off_road and not episode.collided and len(episode.speeds) == 3
    with pytest.raises(RoadFrameError, match="is more than 8.0 m from the lanes"):  # on no road from the start
        Rollout(scenario, _StartOffRoad(small("grid").driver(), beyond=12.0), seed=3, duration=2.0).run()
