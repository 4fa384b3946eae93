"""The package keeps its layer order (driveopt.layers.LAYERS); the project's licence and citation agree with it."""

from pathlib import Path

import pytest

from driveopt import layers

ROOT = Path(__file__).resolve().parents[1]


def test_every_part_imports_only_parts_of_earlier_layers():
    assert layers.violations(ROOT / "src") == []


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / "driveopt" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_an_upward_import_is_named_with_its_file_and_line(tmp_path):
    src = _package(tmp_path, {"__init__.py": "", "low.py": "x = 1\n\n\ndef f():\n    from driveopt.high import y\n",
                              "high/__init__.py": "", "high/deep.py": "from ..high import z\nfrom . import w\n"})
    assert layers.violations(src, (("low",), ("high",))) == [
        "driveopt/low.py:5: low imports high, which is not in a layer before low's"]
    assert layers.violations(src, (("high",), ("low",), ("gone",))) == ["part 'gone' is listed but does not exist"]


def test_parts_of_one_layer_may_not_import_each_other_and_every_part_is_listed(tmp_path):
    src = _package(tmp_path, {"a.py": "import driveopt.b\n", "b.py": "", "c.py": ""})
    assert layers.violations(src, (("a", "b"),)) == [
        "driveopt/a.py:1: a imports b, which is not in a layer before a's", "part 'c' is in no layer of driveopt.layers.LAYERS"]
    assert layers.violations(src, (("b", "c"), ("a",))) == []


def test_the_licence_and_citation_agree_with_the_package():
    import tomllib

    import driveopt

    yaml = pytest.importorskip("yaml")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert (ROOT / "LICENSE").read_text().splitlines()[0] == f"{project['license']['text']} License"
    assert citation["license"] == project["license"]["text"]
    assert citation["version"] == project["version"] == driveopt.__version__
    titles = [reference["title"] for reference in citation["references"]]
    assert any(title.startswith("Bi-Level Optimization Augmented") for title in titles)
    assert any(title.startswith("Learning Sampling Distribution and Safety Filter") for title in titles)
