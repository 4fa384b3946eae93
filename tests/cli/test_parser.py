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


def _seed_options(parser: argparse.ArgumentParser, command: tuple[str, ...] = ()):
    """(command words, option) of every ``--seed`` and ``--seeds`` option of ``parser`` and its subcommands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, subparser in action.choices.items():
                yield from _seed_options(subparser, (*command, name))
        elif {"--seed", "--seeds"} & set(action.option_strings):
            yield command, action.option_strings[0]


def test_every_seed_option_refuses_a_seed_beyond_the_simulators_range_when_parsed(capsys):
    """``collect --seed 200000000000000`` ended in an OverflowError traceback after the file was opened; the trainers
    and ``bench`` took any integer too."""
    from driveopt.cli import build_parser

    options = list(_seed_options(build_parser()))
    commands = {" ".join(command) for command, _ in options}
    assert {"collect", "bench", "drive", "plan", "reproduce", "train cvae", "train filter", "trace-episode"} <= commands
    for command, option in options:
        for value in ("200000000000000", str(2**32), "-1", "10" * 200):
            with pytest.raises(SystemExit) as info:
                build_parser().parse_args([*command, option, value])
            err = capsys.readouterr().err
            assert info.value.code == 2, (command, option, value)
            assert f"argument {option}: seed must be in [0, 4294967295]" in err and err.count("\n") == 1, (command, err)


def _commands(parser: argparse.ArgumentParser, command: tuple[str, ...] = ()):
    """(command words, parser) of ``parser`` and every subcommand's, nested ones included."""
    yield command, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, subparser in action.choices.items():
                yield from _commands(subparser, (*command, name))


def test_every_options_default_is_shown_in_help(monkeypatch):
    from driveopt.cli import build_parser

    monkeypatch.setenv("COLUMNS", "2000")  # one line per option: no value broken at a hyphen

    checked = 0
    for command, parser in _commands(build_parser()):
        text = " ".join(parser.format_help().split())  # the wrapped lines joined
        for action in parser._actions:
            if (not action.option_strings or action.required
                    or isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction))):
                continue
            assert action.help, f"driveopt {' '.join(command)} {action.option_strings[-1]} has no help"
            assert "default" in action.help.lower() or "(default: " in parser._get_formatter()._get_help_string(action), \
                (command, action.option_strings)
            if isinstance(action.default, (int, float, str)) and not isinstance(action.default, bool) \
                    and "default" not in action.help.lower():
                assert f"(default: {action.default})" in text, (command, action.option_strings)
            checked += 1
    assert checked > 100
    drive = " ".join(dict(_commands(build_parser()))[("drive",)].format_help().split())
    assert "--seed SEED traffic and sampling seed (default: 42)" in drive
    assert "(default: none)" in drive  # --json: nothing written unless given


def test_version_prints_the_package_version(capsys):
    import driveopt
    from driveopt.cli import build_parser

    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out.strip() == f"driveopt {driveopt.__version__}"
