"""The README's demonstrations table for collected files: episodes, collisions, rows, modes per row, lanes per row.

    python benchmarks/studies/demonstrations_table.py FILE.h5 [FILE2.h5 ...] [--json OUT.json]

Per file: :func:`driveopt.data.demonstrations.describe` (rows, episodes, collided episodes, ``modes_per_row``:
{"k": rows with k modes}) and ``mode_lanes_per_row`` ({"k": rows whose modes reach k distinct target lanes},
:func:`driveopt.data.replay.mode_lanes`; "0" counts the rows without modes). Prints one table row per file and
writes the JSON when asked. A file that is missing, corrupted or of schema version 1 stops it with a message.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from driveopt.data.demonstrations import describe, load_demonstrations, mode_distribution
from driveopt.data.replay import mode_lanes
from driveopt.errors import DriveoptError
from driveopt.files import write_json


def summary(path: Path) -> dict:
    data = load_demonstrations(path)
    out = describe(data)
    out["mode_lanes_per_row"] = mode_distribution(mode_lanes(data))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path, help="demonstrations (HDF5, schema version 2)")
    parser.add_argument("--json", type=Path, help="write {file: summary} here")
    args = parser.parse_args(argv)
    try:
        results = {str(p): summary(p) for p in args.files}
    except DriveoptError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    number = lambda n: f"{n:,}".replace(",", " ")  # noqa: E731
    group = lambda counts: " / ".join(number(n) for n in counts.values())  # noqa: E731
    for name, s in results.items():
        lanes = dict(s["mode_lanes_per_row"])
        lanes.pop("0", None)
        print(f"| {Path(name).stem} | {s['episodes']} ({s['collided_episodes']}) | {number(s['rows'])} | "
              f"{group(s['modes_per_row'])} | {group(lanes)} |")
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
