import pytest

from driveopt.checks import ConfigError
from driveopt.config import PlannerConfig, SamplerConfig, from_dict, to_dict


def test_round_trip_and_hashable():
    cfg = PlannerConfig().replace(sampler={"num_samples": 250, "feasibility_first": False}, projection={"max_iterations": 100},
                                  stop_rows=False)
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
        ({"cost": {"speed": -1.0}}, "cost.speed"),
        ({"sampler": 5}, "mapping"),
        ({"sampler": {"feasibility_first": "false"}}, "sampler.feasibility_first must be true or false"),
        ({"stop_rows": 0}, "stop_rows must be true or false"),
        ({"stop_rowz": False}, "valid: .*stop_rows"),
        ({"sampler": {"num_samples": 10, "num_constraint_elites": 10, "num_elites": 5, "refine_samples": 11}}, "refine_samples"),
        ({"sampler": {"refine_iterations": 0}}, "refine_iterations"),
    ],
)
def test_bad_config_is_rejected(data, needle):
    with pytest.raises(ConfigError, match=needle):
        from_dict(data)


def test_sampler_rejects_bad_learning_rate():
    with pytest.raises(ConfigError):
        SamplerConfig(learning_rate=0.0)


def test_fewer_samples_cap_the_refined_ones():
    cfg = PlannerConfig().replace(sampler={"refine_samples": 50})
    assert cfg.with_samples(20).sampler.refine_samples == 20 and cfg.with_samples(250).sampler.refine_samples == 50
