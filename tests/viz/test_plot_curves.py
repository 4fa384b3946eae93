"""``driveopt plot-curves``: training curves of `driveopt train` folders, and one-line errors for malformed ones."""

from __future__ import annotations

import json

import matplotlib.image
import numpy as np
import pytest

from driveopt.cli import main
from driveopt.viz.curves import COLUMNS, read_curve

HEADER = "step,collision_rate,mean_return,mean_speed,episodes,wall_s,train_steps_per_s"  # driveopt.training.rl.CURVE_FIELDS
ROWS = ("200,1.0,-0.36,8.66,2,108.7,1.87", "1000,0.5,3.25,17.5,2,300.1,4.2", "2000,0.0,12.5,21.25,2,512.0,4.9")


def _run(root, name, rows=ROWS, header=HEADER, summary=None):
    folder = root / name
    folder.mkdir()
    (folder / "curve.csv").write_text("\n".join([header, *rows]) + "\n")
    if summary is not None:
        (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def test_plot_curves_draws_every_run(tmp_path, capsys):
    dqn = _run(tmp_path, "dqn-run", summary={"algo": "dqn", "scenario": "four-lane-d3.0", "steps": 2000})
    ppo = _run(tmp_path, "ppo-run", rows=ROWS[:1])  # one evaluation, no summary yet (run still going)
    out = tmp_path / "docs" / "rl-curves.png"  # parent folder created
    assert main(["plot-curves", str(dqn), str(ppo / "curve.csv"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "dqn four-lane-d3.0" in printed and "ppo-run" in printed
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 100 and image.shape[1] > 100 and image.std() > 0


def test_read_curve_keeps_the_rows_in_order_with_the_label_from_the_summary(tmp_path):
    curve = read_curve(_run(tmp_path, "run", summary={"algo": "ppo", "scenario": "two-lane-d1.0"}))
    assert curve.label == "ppo two-lane-d1.0" and curve.path == tmp_path / "run" / "curve.csv"
    np.testing.assert_array_equal(curve.steps, [200, 1000, 2000])
    np.testing.assert_array_equal(curve.collision_rate, [1.0, 0.5, 0.0])
    np.testing.assert_array_equal(curve.mean_return, [-0.36, 3.25, 12.5])
    np.testing.assert_array_equal(curve.mean_speed, [8.66, 17.5, 21.25])
    assert read_curve(_run(tmp_path, "no-summary")).label == "no-summary"
    assert read_curve(_run(tmp_path, "odd-summary", summary={"steps": 5})).label == "odd-summary"
    assert set(COLUMNS) <= set(HEADER.split(","))


@pytest.mark.parametrize(("name", "header", "rows", "needle"), [
    ("missing", None, None, "no such file"),
    ("no-column", HEADER.replace("mean_speed,", ""), [r.rsplit(",", 4)[0] + ",2,1.0,1.0" for r in ROWS], "mean_speed"),
    ("not-a-number", HEADER, [ROWS[0], ROWS[1].replace("3.25", "abc")], "'abc'"),
    ("not-finite", HEADER, [ROWS[0].replace("8.66", "nan")], "'nan'"),
    ("short-row", HEADER, ["200,1.0"], "missing"),
    ("header-only", HEADER, [], "no evaluation rows"),
    ("zero-bytes", "", [], "missing column"),
])
def test_malformed_curve_is_a_one_line_error_naming_the_file(tmp_path, capsys, name, header, rows, needle):
    if header is None:
        (tmp_path / name).mkdir()
    else:
        _run(tmp_path, name, rows=rows, header=header)
    out = tmp_path / "curves.png"
    assert main(["plot-curves", str(tmp_path / name), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("driveopt: error: ") and "\n" not in err
    assert str(tmp_path / name / "curve.csv") in err and needle in err
    assert not out.exists()


def test_bad_summary_and_bad_out_are_errors(tmp_path, capsys):
    run = _run(tmp_path, "run")
    (run / "summary.json").write_text("{not json")
    assert main(["plot-curves", str(run), "--out", str(tmp_path / "c.png")]) == 2
    assert "summary.json" in capsys.readouterr().err
    good = _run(tmp_path, "good")
    assert main(["plot-curves", str(good), "--out", str(tmp_path)]) == 2  # a directory
    assert "is a directory" in capsys.readouterr().err
