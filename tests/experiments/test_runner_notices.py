"""A bench or collect episode whose planner compiled says so in one line above the progress bar."""

from __future__ import annotations

from driveopt.experiments.runner import compile_ahead, compile_notice


class Bar:
    def __init__(self, disable=False):
        self.lines, self.disable = [], disable

    def write(self, line, file=None):
        self.lines.append(line)


def test_a_compilation_is_one_line_and_a_cached_load_is_silent():
    bar = Bar()
    compile_notice(bar, "bilevel", 12.34)
    compile_notice(bar, "bilevel", 0.2)
    assert bar.lines == ["driveopt: bilevel compiled in 12.3 s (once per worker and planner; the compilation cache "
                         "keeps it for later runs)"]
    quiet = Bar(disable=True)
    compile_notice(quiet, "bilevel", 12.34)
    assert quiet.lines == []


def test_the_episodes_that_compile_are_announced_before_they_start():
    bar = Bar()
    compile_ahead(bar, ["bilevel", "grid"])
    compile_ahead(bar, [])  # nothing to run: nothing to say
    compile_ahead(Bar(disable=True), ["bilevel"])
    assert bar.lines == ["driveopt: each worker's first episode of bilevel, grid compiles it unless the compilation "
                         "cache holds it (tens of seconds; the bar waits meanwhile) ..."]
