"""benchmarks/perf/compile_cost.py: every case's options are ones this jaxlib's CPU compiler accepts; bad runs are refused."""

from __future__ import annotations

import json

import jax
import pytest

from driveopt.xla import XLA_CPU_COMPILER_OPTIONS, supported_compiler_options

from benchmarks.perf import compile_cost


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="CPU compiler options")
def test_every_case_is_accepted_by_the_cpu_compiler():
    for name, options in compile_cost.CASES.items():
        merged = {**XLA_CPU_COMPILER_OPTIONS, **options}
        assert supported_compiler_options(merged) == merged, name


def test_memory_mappings_are_counted_where_linux_lists_them():
    count = compile_cost.mappings()
    assert count is None or count > 10


@pytest.mark.parametrize("argv", [["--calls", "0", "--json", "x.json"], ["--samples", "0", "--json", "x.json"], []])
def test_bad_runs_are_refused_before_anything_compiles(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        compile_cost.main(argv)
    assert stop.value.code == 2 and "compile_cost.py: error:" in capsys.readouterr().err


def test_a_file_from_other_settings_is_not_extended(tmp_path, capsys):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"calls": 3, "samples": 250, "cases": []}))
    with pytest.raises(SystemExit, match="holds a run with other --calls/--samples"):
        compile_cost.main(["--json", str(path), "--calls", "10"])
