"""Outputs whole or absent, checked before the long work, in strict JSON; one writer per output file; default paths
outside the tracked files."""

from __future__ import annotations

import errno
import json
import math
import os
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from driveopt import files
from driveopt.cli import main
from driveopt.files import OutputError, OutputInUseError, json_text, lock_output_file, write_json

DRIVE = ["drive", "--scenario", "two-lane-d1.0", "--planner", "idm", "--duration", "0.3"]


def strict_json(text: str):
    """``json.loads`` that refuses NaN, Infinity and -Infinity, as strict parsers do."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    error = captured.err.splitlines()[-1]  # after the progress bar, if any
    assert error.startswith("driveopt: error: ") and captured.err.count("driveopt: error") == 1
    assert "Traceback" not in captured.err and "wrote" not in captured.out
    return error


def disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def disk_full_when_writing(name: str):
    """An ``os.fsync`` for a disk that fills up during the run: the check before it passed, the write of the output
    file ``name`` (its temporary sibling) fails."""
    real = os.fsync

    def fsync(fd):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(f".{name}."):
            disk_full()
        real(fd)

    return fsync


def fail_if_called(*args, **kwargs):
    pytest.fail("the long work ran before the output path was checked")


# --- strict JSON ---------------------------------------------------------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5)
    | st.floats(width=32).map(np.float32) | st.integers(-5, 5).map(np.int64),
    lambda inner: st.lists(inner, max_size=4) | st.tuples(inner, inner) | st.dictionaries(st.text(max_size=4), inner, max_size=4),
    max_leaves=20,
)


def _same_but_missing_numbers(parsed, original) -> bool:
    """``parsed`` is ``original`` with every number that is not finite replaced by None."""
    if isinstance(original, dict):
        return parsed.keys() == original.keys() and all(_same_but_missing_numbers(parsed[k], original[k]) for k in original)
    if isinstance(original, (list, tuple)):
        return len(parsed) == len(original) and all(map(_same_but_missing_numbers, parsed, original))
    if isinstance(original, (float, np.floating)):
        return parsed is None if not math.isfinite(original) else parsed == float(original)
    if isinstance(original, np.integer):
        return parsed == int(original)
    return parsed == original


@settings(max_examples=200, deadline=None, derandomize=True)
@given(json_values)
def test_json_output_is_strict_and_keeps_every_finite_value(value):
    """Python's json writes NaN and Infinity, which strict parsers reject; a missing number is null instead."""
    for indent in (1, None):
        assert _same_but_missing_numbers(strict_json(json_text(value, indent)), value)


def test_plan_and_drive_json_are_strict_with_null_for_what_is_missing(tmp_path, capsys):
    """idm never plans: its plan times are null, not 0 and not NaN (plan's JSON: tests/cli/test_cli.py)."""
    out = tmp_path / "drive.json"
    assert main([*DRIVE, "--video", "", "--json", str(out)]) == 0
    summary = strict_json(out.read_text())
    assert summary["plan_ms_median"] is None and summary["plan_ms_p95"] is None and summary["planner"] == "idm"
    assert "no planning calls" in capsys.readouterr().out


def test_collect_json_is_strict_and_checked_before_collecting(tmp_path, capsys, monkeypatch):
    """`collect --json DIR` failed only after collecting."""
    from driveopt.experiments import collect

    argv = ["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--out", str(tmp_path / "demo.h5")]
    monkeypatch.setattr(collect, "execute", fail_if_called)
    assert "is a directory" in one_line_error(capsys, [*argv, "--json", str(tmp_path)])
    assert "cannot be written" in one_line_error(capsys, [*argv, "--json", "/proc/version"])
    assert not (tmp_path / "demo.h5").exists()
    monkeypatch.setattr(collect, "execute", lambda *args, **kwargs: None)  # every episode already collected
    assert main([*argv, "--json", str(tmp_path / "summary.json")]) == 0
    summary = strict_json((tmp_path / "summary.json").read_text())
    assert summary["episodes"] == 0 and summary["settings"]["samples"] == 250


# --- whole or absent ---------------------------------------------------------------------------------------------


def test_a_write_on_a_full_disk_keeps_the_previous_file_and_leaves_nothing_else(tmp_path, monkeypatch):
    path = tmp_path / "result.json"
    path.write_text("previous")
    monkeypatch.setattr(files.os, "fsync", disk_full)
    with pytest.raises(OutputError, match=f"cannot write {path}: No space left on device") as caught:
        write_json(path, {"a": 1})
    assert isinstance(caught.value, OSError)  # callers that caught failed writes keep catching them
    assert path.read_text() == "previous" and sorted(tmp_path.iterdir()) == [path]


def test_drive_json_on_a_full_disk_is_one_line_and_leaves_no_file(tmp_path, capsys, monkeypatch):
    """--json on a full disk gave a traceback and a 0-byte file."""
    out = tmp_path / "drive.json"
    monkeypatch.setattr(files.os, "fsync", disk_full_when_writing(out.name))
    err = one_line_error(capsys, [*DRIVE, "--video", "", "--json", str(out)])
    assert f"cannot write {out}: No space left on device" in err
    assert list(tmp_path.iterdir()) == []


def test_drive_video_on_a_full_disk_is_an_error_not_wrote(tmp_path, capsys, monkeypatch):
    """The MP4 was cut at 4 KB by a full disk and drive still printed "wrote": the file size limit of this process,
    which ffmpeg inherits, stands for the disk (writes past it fail as they would on a full one). Modules first
    imported under the limit write no bytecode (it would be cut too, and break later imports)."""
    resource = pytest.importorskip("resource")
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    video = tmp_path / "drive.mp4"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, hard))
    try:
        err = one_line_error(capsys, [*DRIVE, "--duration", "1.0", "--video", str(video)])
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert f"cannot write {video}" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, needle", [
    (["plan", "--plot", "x.txt"], "--plot x.txt: expected a file ending in"),
    (["plan", "--json", "/proc/version"], "--json /proc/version cannot be written"),
    (["plan", "--plot", "/proc/plan.png"], "--plot /proc/plan.png cannot be written"),
    ([*DRIVE, "--video", "v.txt"], "--video v.txt: expected a file ending in .mp4, got '.txt'"),
    ([*DRIVE, "--video", "", "--json", "/proc/version"], "--json /proc/version cannot be written"),
    (["plot-curves", "run", "--out", "curves.txt"], "--out curves.txt: expected a file ending in"),
])
def test_output_paths_are_checked_before_the_work(tmp_path, capsys, monkeypatch, argv, needle):
    """plan --json/--plot tracebacked only after planning; --plot x.txt, --video v.txt, --json /proc/version
    tracebacked."""
    from driveopt import planner
    from driveopt.experiments import rollout

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(planner, "plan", fail_if_called)
    monkeypatch.setattr(rollout.Rollout, "__iter__", fail_if_called)
    assert needle in one_line_error(capsys, argv)
    assert list(tmp_path.iterdir()) == []


# --- one writer --------------------------------------------------------------------------------------------------


def test_a_second_collect_into_the_same_file_is_refused(tmp_path, capsys, monkeypatch):
    from driveopt.experiments import collect

    monkeypatch.setattr(collect, "execute", fail_if_called)
    out = tmp_path / "demo.h5"
    with lock_output_file(out):  # another collection holds the file
        err = one_line_error(capsys, ["collect", "--scenarios", "two-lane-d1.0", "--episodes", "1", "--out", str(out)])
    assert f"the output file {out} is in use by another run (PID {os.getpid()})" in err
    assert not out.exists()


def test_the_lock_is_released_when_its_holder_ends(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    with files.lock_output_folder(folder):
        with pytest.raises(OutputInUseError, match="in use by another run"), files.lock_output_folder(folder):
            pass
    with files.lock_output_folder(folder):  # free again
        pass


# --- default output paths ----------------------------------------------------------------------------------------


def test_plot_curves_without_out_writes_under_the_working_directory_s_out(tmp_path, capsys, monkeypatch):
    """plot-curves without --out overwrote the repository's docs/rl-curves.png when run from it."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "curve.csv").write_text("step,collision_rate,mean_return,mean_speed\n200,1.0,-0.4,8.7\n1000,0.5,3.2,17.5\n")
    monkeypatch.chdir(tmp_path)
    assert main(["plot-curves", str(run)]) == 0
    assert (tmp_path / "out" / "rl-curves.png").stat().st_size > 0 and not (tmp_path / "docs").exists()
    assert "out/rl-curves.png" in capsys.readouterr().out
