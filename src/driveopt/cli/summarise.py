"""``driveopt summarise``: one summary table (and csv, plot) over the episodes of several bench folders.

Each ``driveopt bench`` run writes its own folder; tables that compare planners run in separate folders
(or at separate commits) are merged here, and every planner is compared episode by episode with the
reference planner (``--reference``, default ``idm``) where the folders hold it for the same traffic. Every record is
checked as it is read (:func:`driveopt.experiments.store.load_folder`: its fields, one per episode, the settings of
its folder's ``spec.json``); the summaries are written whole while this run holds the output folder.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from driveopt.cli.common import UsageError
from driveopt.files import lock_output_folder, make_output_folder


def register(sub) -> None:
    p = sub.add_parser("summarise", help="merge bench folders into one summary table, compared with a reference planner")
    p.add_argument("folders", nargs="+", help="bench output folders (or their episodes.jsonl files)")
    p.add_argument("--reference", default="idm", help="planner the others are compared with, episode by episode (default idm)")
    p.add_argument("--out", default="out/summary", help="folder for summary.md, summary.csv, summary.json, summary.png")
    p.set_defaults(func=run)


def _records_file(folder: str) -> Path:
    path = Path(folder)
    path = path / "episodes.jsonl" if path.is_dir() else path
    if not path.is_file():
        raise UsageError(f"{folder}: no bench results there (expected a bench output folder or its episodes.jsonl)")
    return path


def run(args: argparse.Namespace) -> int:
    from driveopt.experiments.bench import write_summaries
    from driveopt.experiments.store import key_of, load_folder
    from driveopt.experiments.summary import markdown_table, summarise

    seen: dict[tuple, Path] = {}
    records = []
    for folder in args.folders:
        path = _records_file(folder)
        for record in load_folder(path)[1]:
            key = key_of(record)
            if key in seen:
                raise UsageError(f"{path} and {seen[key]} both hold {key.planner} on {key.scenario}, seed {key.seed}, "
                                 f"episode {key.episode}: pass each run once")
            seen[key] = path
            records.append(record)
    if not records:
        raise UsageError("the folders hold no finished episodes")
    rows = summarise(records, args.reference)
    out = make_output_folder(args.out, UsageError, "summary.md, summary.csv, summary.json, summary.png")
    with lock_output_folder(out):
        write_summaries(rows, out)
    print(markdown_table(rows))
    print(f"wrote {out}/summary.md, summary.csv, summary.json, summary.png")
    return 0
