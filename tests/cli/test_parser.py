"""The command line's parser: usage errors are one line ``driveopt: error: ...`` and status 2, as every user error."""

from __future__ import annotations

import argparse

import pytest

from driveopt.cli.common import positive_int
from driveopt.cli.parser import OneLineArgumentParser, duration


def _parser() -> OneLineArgumentParser:
    parser = OneLineArgumentParser(prog="driveopt")
    sub = parser.add_subparsers(dest="command", required=True)
    drive = sub.add_parser("drive")
    drive.add_argument("--samples", type=positive_int)
    drive.add_argument("--duration", type=duration)
    drive.add_argument("--mode", choices=["a", "b"])
    return parser


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["drive", "--samples", "0"], "argument --samples: expected an integer >= 1, got 0"),
        (["drive", "--duration", "1e300"], "argument --duration: duration must be in (0, 3600] s, got 1e+300"),
        (["drive", "--duration", "1e308"], "argument --duration: duration must be in (0, 3600] s"),
        (["drive", "--duration", "inf"], "argument --duration: duration must be a finite number"),
        (["drive", "--duration", "nan"], "argument --duration: duration must be a finite number"),
        (["drive", "--duration", "-1"], "argument --duration: duration must be in (0, 3600] s"),
        (["drive", "--duration", "long"], "argument --duration: expected a duration in seconds, got 'long'"),
        (["drive", "--mode", "c"], "argument --mode: invalid choice: 'c'"),
        (["drive", "--colour"], "unrecognized arguments: --colour"),
        (["fly"], "argument command: invalid choice: 'fly'"),
        ([], "the following arguments are required: command"),
    ],
)
def test_usage_errors_are_one_line_and_status_2(capsys, argv, needle):
    with pytest.raises(SystemExit) as info:
        _parser().parse_args(argv)
    assert info.value.code == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("driveopt: error: ") and needle in captured.err
    assert captured.err.count("\n") == 1 and "usage:" not in captured.err and captured.out == ""


def test_the_error_names_the_command_to_ask_for_help(capsys):
    with pytest.raises(SystemExit):
        _parser().parse_args(["drive", "--samples", "x"])
    assert capsys.readouterr().err.rstrip().endswith("(see driveopt drive --help)")


def test_help_still_prints_the_usage(capsys):
    with pytest.raises(SystemExit) as info:
        _parser().parse_args(["drive", "--help"])
    assert info.value.code == 0 and "usage: driveopt drive" in capsys.readouterr().out


def test_a_valid_duration_is_a_float():
    assert _parser().parse_args(["drive", "--duration", "20"]).duration == 20.0
    assert isinstance(duration("1e3"), float)
    with pytest.raises(argparse.ArgumentTypeError):
        duration("3601")
