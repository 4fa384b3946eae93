import pytest

from driveopt.checks import ConfigError
from driveopt.config import PlannerConfig, SamplerConfig, from_dict, to_dict
from driveopt.fallback import Fallback
from driveopt.ranking import CostPlusResidual, FeasibilityFirst


def test_round_trip_and_hashable():
    cfg = PlannerConfig().replace(sampler={"num_samples": 250, "structured_fraction": 0.0}, projection={"max_iterations": 100},
                                  qp={"initial_lateral_acceleration": True})
    assert from_dict(to_dict(cfg)) == cfg
    assert hash(cfg) == hash(from_dict(to_dict(cfg)))


@pytest.mark.parametrize(
    "data, needle",
    [
        ({"samplr": {}}, "unknown config section"),
        ({"sampler": {"num_sample": 3}}, "unknown key"),
        ({"sampler": {"num_samples": 10, "num_constraint_elites": 20}}, "num_constraint_elites"),
        ({"projection": {"v_min": 40.0}}, "v_min"),
        ({"projection": {"course_max": 1.6}}, "course_max must be in"),
        ({"projection": {"course_max": -0.1}}, "course_max must be in"),
        ({"projection": {"course_min_speed": -1.0}}, "course_min_speed must be in"),
        ({"projection": {"ego_turn_rate": -0.1}}, "ego_turn_rate must be in"),
        ({"projection": {"anderson_window": -1}}, "anderson_window must be in"),
        ({"projection": {"anderson_window": 3.0}}, "anderson_window must be"),
        ({"projection": {"relaxation": 2.0}}, "relaxation must be in"),
        ({"projection": {"relaxation": 0.0}}, "relaxation must be in"),
        ({"projection": {"derivative_bounds": "knots"}},
         "projection.derivative_bounds must be one of 'nodes', 'control_points', got 'knots'"),
        ({"projection": {"derivative_bounds": True}}, "projection.derivative_bounds must be one of"),
        ({"projection": {"derivative_pieces": 0}}, "projection.derivative_pieces must be in \\[1, 16\\], got 0"),
        ({"projection": {"nearest_obstacles": -1}}, "projection.nearest_obstacles must be in \\[0, 1000\\], got -1"),
        ({"projection": {"nearest_choice": "node"}},
         "projection.nearest_choice must be one of 'sample', 'batch', got 'node'"),
        ({"projection": {"nearest_obstacles": 4, "barrier": True}},
         "projection.nearest_obstacles > 0 needs projection.barrier = false"),
        ({"projection": {"obstacle_stride": 0}}, "projection.obstacle_stride must be in \\[1, 16\\], got 0"),
        ({"projection": {"obstacle_dense_time": -1.0}}, "projection.obstacle_dense_time must be in \\[0, 120\\] s"),
        ({"projection": {"obstacle_stride": 4, "barrier": True}},
         "projection.obstacle_stride > 1 needs projection.barrier = false and nearest_obstacles = 0"),
        ({"projection": {"obstacle_stride": 4, "nearest_obstacles": 4}}, "projection.obstacle_stride > 1 needs"),
        ({"cost": {"speed": -1.0}}, "cost.speed"),
        ({"sampler": 5}, "mapping"),
        ({"projection": {"barrier": "false"}}, "projection.barrier must be true or false"),
        ({"stop_rows": False}, "unknown config section 'stop_rows'; valid: .*sampler"),
        ({"sampler": {"feasibility_first": False}}, "unknown key"),
    ],
)
def test_bad_config_is_rejected(data, needle):
    with pytest.raises(ConfigError, match=needle):
        from_dict(data)


def test_sampler_rejects_bad_learning_rate():
    with pytest.raises(ConfigError):
        SamplerConfig(learning_rate=0.0)


def test_fewer_samples_cap_the_elites():
    cfg = PlannerConfig().with_samples(20).sampler
    assert (cfg.num_samples, cfg.num_constraint_elites, cfg.num_elites) == (20, 20, 20)
    cfg = PlannerConfig().with_samples(250).sampler
    assert (cfg.num_samples, cfg.num_constraint_elites, cfg.num_elites) == (250, 100, 40)


@pytest.mark.parametrize("make", [lambda: FeasibilityFirst(0.0), lambda: CostPlusResidual(float("nan")),
                                  lambda: Fallback(deceleration=0.0), lambda: Fallback(evasion="yes")])
def test_bad_strategies_are_rejected(make):
    with pytest.raises(ConfigError):
        make()


@pytest.mark.parametrize(
    "data, needle",
    [
        ({"basis": {"horizon": 1e-30}}, "basis.horizon must be in [1, 120] s"),
        ({"basis": {"horizon": 0.5}}, "basis.horizon must be in [1, 120] s"),
        ({"sampler": {"temperature": 1e-300}}, "sampler.temperature must be in [1e-06, 1e+06]"),
        ({"sampler": {"num_samples": 100_000, "num_iterations": 1000}, "projection": {"max_iterations": 10_000}},
         "planning work per call"),
        ({"sampler": {"num_samples": 100_000, "num_iterations": 1}, "basis": {"num_nodes": 2000},
          "projection": {"max_iterations": 1}}, "planning memory per call"),
    ],
)
def test_degenerate_and_unrunnable_configs_are_refused(monkeypatch, data, needle):
    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE", raising=False)
    with pytest.raises(ConfigError) as info:
        from_dict(data)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_the_work_and_memory_limits_name_the_way_past_them(monkeypatch):
    big = {"sampler": {"num_samples": 100_000, "num_iterations": 1000}, "projection": {"max_iterations": 10_000}}
    monkeypatch.delenv("DRIVEOPT_ALLOW_LARGE", raising=False)
    with pytest.raises(ConfigError, match=r"1e\+14 \(about .* hours a call on 2 CPU cores\).*DRIVEOPT_ALLOW_LARGE=1"):
        from_dict(big)
    monkeypatch.setenv("DRIVEOPT_ALLOW_LARGE", "1")
    assert from_dict(big).sampler.num_samples == 100_000


def test_the_limits_leave_the_registered_planners_room():
    from driveopt.config import MAX_PLANNING_WORK, MAX_SAMPLE_NODES, planning_work
    from driveopt.registry import get_planner, list_planners

    configs = {name: getattr(get_planner(name), "config", None) for name in list_planners()}
    configs = {name: config for name, config in configs.items() if isinstance(config, PlannerConfig)}
    assert configs
    for name, config in configs.items():
        assert planning_work(config) <= MAX_PLANNING_WORK / 100, name
        assert config.sampler.num_samples * config.basis.num_nodes <= MAX_SAMPLE_NODES / 100, name
