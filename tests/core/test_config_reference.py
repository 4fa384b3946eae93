"""docs/configuration.md is generated from config.py's field comments (driveopt.config_reference) and cannot go stale."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from driveopt.config import PlannerConfig
from driveopt.config_reference import COMMAND, field_docs, render

PAGE = Path(__file__).resolve().parents[2] / "docs" / "configuration.md"


def test_the_committed_configuration_reference_is_the_generators_output():
    assert PAGE.read_text(encoding="utf-8") == render(), f"docs/configuration.md is stale: run `{COMMAND}`"


def test_every_field_has_a_row_with_a_unit_and_a_description():
    rows = {f"{r.section}.{r.name}": r for rows in field_docs().values() for r in rows}
    fields = {f"{s.name}.{f.name}" for s in dataclasses.fields(PlannerConfig)
              for f in dataclasses.fields(getattr(PlannerConfig(), s.name))}
    assert set(rows) == fields
    assert all(r.unit and r.description and r.default for r in rows.values())
    assert rows["basis.horizon"].unit == "s" and rows["basis.order"].unit == "-"
    assert rows["qp.k_d"].default.startswith("8.944") and rows["qp.initial_acceleration"].default == "true"
    assert rows["projection.ego_turn_rate"].description.endswith("0.179 is highway-env's bicycle at full lock")


def test_a_field_without_a_comment_is_refused():
    from driveopt import config

    source = Path(config.__file__).read_text(encoding="utf-8")
    bare = source.replace("v_max: float = 30.0  # [m/s] speed upper bound", "v_max: float = 30.0")
    assert bare != source
    with pytest.raises(ValueError, match="projection.v_max has no comment"):
        field_docs(bare)


def test_main_writes_the_page(tmp_path, capsys):
    from driveopt.config_reference import main

    assert main([str(tmp_path / "c.md")]) == 0 and (tmp_path / "c.md").read_text(encoding="utf-8") == render()
    assert main([]) == 2
