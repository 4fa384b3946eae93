"""Every folder of Python modules is a regular package, so a non-editable install ships it too."""

from pathlib import Path

import driveopt


def test_every_module_folder_is_a_package_with_a_docstring():
    root = Path(driveopt.__file__).parent
    folders = {p.parent for p in root.rglob("*.py")} - {root}
    missing = sorted(str(f.relative_to(root)) for f in folders if not (f / "__init__.py").exists())
    assert not missing, f"folders without __init__.py (left out of a wheel): {missing}"
    undocumented = sorted(str(f.relative_to(root)) for f in folders if not (f / "__init__.py").read_text().lstrip().startswith('"""'))
    assert not undocumented, f"packages without a docstring saying what lives there: {undocumented}"
