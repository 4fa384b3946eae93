"""The configuration reference, ``docs/configuration.md``, written from :mod:`driveopt.config` itself.

Every field of a :class:`~driveopt.config.PlannerConfig` section carries its unit and meaning in the comment on its line
(``name: type = default  # [unit] what it does``, continued on the comment lines below it); this module reads those
comments, the defaults as written and the sections' docstrings from ``config.py`` and renders them as one table per
section, so the page cannot drift from the code. Regenerate it from the repository root with

    python -m driveopt.config_reference docs/configuration.md

(``tests/core/test_config_reference.py`` fails while the committed page differs from :func:`render`).
"""

from __future__ import annotations

import ast
import dataclasses
import io
import json
import re
import sys
import tokenize
from pathlib import Path

from driveopt import config as config_module
from driveopt.config import (BYTES_PER_SAMPLE_NODE, COMPILE_BYTES_PER_OBSTACLE, COMPILE_SECONDS_PER_OBSTACLE, MAX_OBSTACLES,
                             MAX_PLANNING_WORK, MAX_SAMPLE_NODES, PLANNING_WORK_PER_SECOND, REFERENCE_OBSTACLES,
                             RUNTIME_FIELDS, PlannerConfig)

COMMAND = "python -m driveopt.config_reference docs/configuration.md"

_UNIT = re.compile(r"^\[([^\]]*)\]\s*")


@dataclasses.dataclass(frozen=True)
class FieldDoc:
    """One row of the reference: ``section.name``, its default as written in ``config.py``, its unit, its meaning."""

    section: str
    name: str
    default: str
    unit: str
    description: str


def _comments(source: str) -> dict[int, str]:
    """Line number -> the text of the comment on that line (without ``#``)."""
    found = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            found[token.start[0]] = token.string[1:].strip()
    return found


def _default(node: ast.expr, source: str, value: object) -> str:
    """The default as a reader writes it in a ``--config`` file: JSON for a literal, the value and the expression
    that computes it otherwise."""
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool):
            return json.dumps(node.value)
        return ast.get_source_segment(source, node) or repr(node.value)
    return f"{value:.4g} (`{ast.get_source_segment(source, node)}`)"


def _power(value: float) -> str:
    """1e10 for 1e+10."""
    mantissa, exponent = f"{value:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _markdown(text: str) -> str:
    """A comment's reStructuredText literals as Markdown code, and ``|`` escaped for a table cell."""
    return text.replace("``", "`").replace("|", "\\|")


def field_docs(source: str | None = None) -> dict[str, list[FieldDoc]]:
    """Section name -> its fields' rows, in ``PlannerConfig``'s order, read from ``config.py``'s source."""
    source = Path(config_module.__file__).read_text(encoding="utf-8") if source is None else source
    tree, comments, lines = ast.parse(source), _comments(source), source.splitlines()
    classes = {node.name: node for node in tree.body if isinstance(node, ast.ClassDef)}
    default = PlannerConfig()
    sections: dict[str, list[FieldDoc]] = {}
    for section in dataclasses.fields(PlannerConfig):
        part = getattr(default, section.name)
        body = [node for node in classes[type(part).__name__].body
                if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)]
        names = [node.target.id for node in body]
        expected = [f.name for f in dataclasses.fields(part)]
        if names != expected:
            raise ValueError(f"{type(part).__name__}: fields {names} in the source, {expected} in the class")
        rows = []
        for node in body:
            text = [comments[n] for n in range(node.lineno, node.end_lineno + 1) if n in comments]
            n = node.end_lineno + 1  # the comment continues on the comment-only lines below
            while n <= len(lines) and lines[n - 1].strip().startswith("#"):
                text.append(comments[n])
                n += 1
            comment = " ".join(text)
            if not comment:
                raise ValueError(f"{section.name}.{node.target.id} has no comment in config.py: say what it does")
            match = _UNIT.match(comment)
            unit = match[1] if match else "-"
            description = comment[match.end():] if match else comment
            rows.append(FieldDoc(section.name, node.target.id, _default(node.value, source, getattr(part, node.target.id)),
                                 unit, _markdown(description)))
        sections[section.name] = rows
    return sections


def render(source: str | None = None) -> str:
    """The whole of ``docs/configuration.md``."""
    default = PlannerConfig()
    runtime = ", ".join(f"`{section}.{name}`" for section, names in RUNTIME_FIELDS.items() for name in names)
    minutes = MAX_PLANNING_WORK / PLANNING_WORK_PER_SECOND / 60
    gigabytes = MAX_SAMPLE_NODES * BYTES_PER_SAMPLE_NODE / 1e9
    out = [
        "# Configuration reference",
        "",
        f"<!-- Generated from src/driveopt/config.py by `{COMMAND}`; edit the field comments there. -->",
        "",
        "What each field of `PlannerConfig` (`driveopt.config`) means, its default and its unit. The configuration is",
        "frozen and hashable (a static argument of the compiled planner); `--config FILE` (nested JSON sections, e.g.",
        "`{\"cost\": {\"consistency\": 1.0}}`) and `.replace(section={...})` override a planner's own, type- and",
        "range-checked. Defaults follow P1 unless the row says otherwise ([why](design.md)); cost terms are means over",
        "the nodes (`lane_flow` reads a plan's end). Configurations that differ only in the fields read at run time",
        f"({runtime}) share one compilation ([how](design.md#collision-ellipses-and-compilation)).",
        f"A call above {_power(MAX_PLANNING_WORK)} units of work (samples x iterations x projection iterations x nodes,",
        f"~{minutes:.0f} min on the project's 2-core CPU machine) or {_power(MAX_SAMPLE_NODES)} sample-nodes",
        f"(~{gigabytes:.1f} GB) needs `DRIVEOPT_ALLOW_LARGE=1`, and so does planning against more than {MAX_OBSTACLES}",
        f"obstacles (`max_obstacles`; each adds ~{COMPILE_SECONDS_PER_OBSTACLE:g} s and ~{COMPILE_BYTES_PER_OBSTACLE / 1e6:g} MB "
        f"to the compilation). Both estimates count the obstacles beyond {REFERENCE_OBSTACLES}",
        "(`driveopt.config.check_planning_size`).",
        "",
        "How rows are ranked, what rides in a batch and which stops the fallback weighs are strategies passed to the",
        "planner, not fields: [design.md](design.md#the-planners-strategies).",
    ]
    for section, rows in field_docs(source).items():
        doc = (type(getattr(default, section)).__doc__ or "").strip().splitlines()[0]
        out += ["", f"## `{section}`", "", _markdown(doc), "",
                "| field | default | unit | what it does |", "|---|---|---|---|"]
        out += [f"| `{r.section}.{r.name}` | {r.default} | {r.unit} | {r.description} |" for r in rows]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(f"usage: {COMMAND}", file=sys.stderr)
        return 2
    Path(args[0]).write_text(render(), encoding="utf-8")
    print(f"wrote {args[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
