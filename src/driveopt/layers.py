"""The package's layers, written once: each part of driveopt imports only parts of the layers before its own.

A *part* is a top-level module (``planner``) or subpackage (``sim``) of ``driveopt``; the package's ``__init__``
(lazy re-exports) stands outside the order. Part A imports part B when any module of A imports any module of B,
at the top of a file or inside a function. Parts of one layer import none of each other, so each layer can be read
knowing only the layers above it. ``tests/test_layers.py`` holds the package to this order with
:func:`violations`; a new module is added to the layer it belongs to.
"""

from __future__ import annotations

import ast
from pathlib import Path

LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "lazy", "chunks", "pytree", "compilation_cache", "gym_envs", "layers", "learned_kinds"),  # exceptions,
    # lazy exports, loop helpers, learned weights as pytrees, registered ids, this order, learned components by kind
    ("checks", "jsonfile", "files", "xla", "host_copy"),  # one-line input checks, the strict file reader, atomic writes,
    # compiling, a result's copy to the host
    ("config", "scene", "solve_export"),  # configuration; the world; exported planner graphs
    ("basis", "prediction", "config_reference", "goal"),  # Bernstein basis; neighbours' predicted motion;
    # docs/configuration.md; where a plan should lead
    ("observation", "qp", "anderson"),  # the learned components' features; the set-point QP; fixed-point acceleration
    ("problem", "trajectory"),  # the planner's arrays; a trajectory read out of its coefficients
    ("projection", "costs", "sampler", "filtering", "sim"),  # the numerics; the SafetyFilter contract; highway-env
    ("ranking", "row_sharing", "rl"),  # the planner's strategies; P1's RL baselines
    ("fallback",),
    ("method",),  # ranking, fallback and row sharing as one value
    ("planner",),  # solve() and plan()
    ("multi_plan",),  # many problems in one compiled call (episodes in lock-step)
    ("learned", "data"),  # networks and checkpoints; demonstrations
    ("priors", "safety"),  # first-batch proposals; the learned safety filter
    ("drivers",),  # who acts in the closed loop
    ("faithful", "training"),  # the papers' planners as their authors ran them; training
    ("registry",),  # planner names -> driver specs
    ("experiments",),  # episodes, bench, collect, reproduction
    ("commonroad",),  # CommonRoad scenarios: road frame, evaluator, closed loop, FISS
    ("viz",),
    ("controller", "cli"),  # the user's own env; the command line
    ("sb3",),  # the controller as a Stable-Baselines3 policy and as a gymnasium env
)


def parts(src: Path) -> dict[str, list[Path]]:
    """The parts of the ``driveopt`` package under ``src`` -> their module files."""
    found: dict[str, list[Path]] = {}
    for path in sorted((src / "driveopt").rglob("*.py")):
        relative = path.relative_to(src / "driveopt").parts
        if relative == ("__init__.py",):
            continue
        found.setdefault(Path(relative[0]).stem, []).append(path)
    return found


def _imported(tree: ast.AST, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, dotted name) of every import in ``tree`` of ``module``, relative imports resolved."""
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_package else module.split(".")[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            names += [(node.lineno, base)] + [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return names


def violations(src: Path, layers: tuple[tuple[str, ...], ...] = LAYERS) -> list[str]:
    """Every way the package under ``src`` breaks ``layers``: a part missing from them or listed twice, a listed part
    that does not exist, and each import of a part of the same or a later layer, as ``file:line: a imports b``."""
    found = parts(src)
    listed = [part for layer in layers for part in layer]
    problems = [f"part '{p}' is in no layer of driveopt.layers.LAYERS" for p in found if p not in listed]
    problems += [f"part '{p}' is listed {listed.count(p)} times" for p in sorted(set(listed)) if listed.count(p) > 1]
    problems += [f"part '{p}' is listed but does not exist" for p in listed if p not in found]
    rank = {part: i for i, layer in enumerate(layers) for part in layer}
    for part, files in found.items():
        for path in files:
            module_parts = path.relative_to(src).with_suffix("").parts
            is_package = module_parts[-1] == "__init__"
            module = ".".join(module_parts[:-1] if is_package else module_parts)
            for line, name in _imported(ast.parse(path.read_text(), str(path)), module, is_package):
                bits = name.split(".")
                if bits[0] != "driveopt" or len(bits) < 2 or bits[1] not in found or bits[1] == part:
                    continue
                if part in rank and bits[1] in rank and rank[bits[1]] >= rank[part]:
                    problems.append(f"{path.relative_to(src)}:{line}: {part} imports {bits[1]}, "
                                    f"which is not in a layer before {part}'s")
    return sorted(set(problems))
