"""The scripts of benchmarks/ as modules, for the tests that call their functions and main()."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load(name: str):
    """benchmarks/``name``.py imported as the module ``name`` (in ``sys.modules``, so that worker processes can unpickle
    its functions), with benchmarks/ on the import path as when the script runs (a script may import its sibling
    modules)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.append(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
