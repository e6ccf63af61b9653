"""The package's layers hold: import-linter's contracts (pyproject.toml) pass, and they catch what they forbid.

grimp reads every import statement of the package, also those inside function bodies, so a lazy import
that reaches into a higher room breaks the contract as a top-level one does.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = REPO / "pyproject.toml"
LINT = textwrap.dedent("""
    import sys
    from importlinter import api  # noqa: F401  (configures import-linter)
    from importlinter.application import use_cases
    kept = use_cases.lint_imports(config_filename=sys.argv[1], cache_dir=None, no_logo=True)
    sys.exit(0 if kept else 1)
""")


def lint(package_parent: Path, config: Path = PYPROJECT) -> subprocess.CompletedProcess:
    """import-linter on the ``plm_highway`` package found in ``package_parent``, in a process of its own (grimp
    finds the package on sys.path)."""
    env = {**os.environ, "PYTHONPATH": str(package_parent)}
    return subprocess.run([sys.executable, "-c", LINT, str(config)], cwd=package_parent, env=env,
                          capture_output=True, text=True, timeout=300)


def contracts() -> list[dict]:
    return tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["tool"]["importlinter"]["contracts"]


def test_the_package_keeps_every_contract():
    result = lint(REPO)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "3 kept, 0 broken" in result.stdout


def test_the_layers_name_every_room_from_the_command_line_down():
    [layers] = [c for c in contracts() if c["type"] == "layers"]
    assert layers["exhaustive"] is True  # a new room must be placed before anything imports it
    flat = [name.strip() for line in layers["layers"] for name in line.split("|")]
    order = {name.strip("()"): k for k, name in enumerate(flat)}
    # top to bottom: each room sits above what it builds on
    for upper, lower in [("cli", "population"), ("population", "sweep"), ("sweep", "evaluation"),
                         ("evaluation", "training"), ("training", "data"), ("data", "rollout"),
                         ("rollout", "lane_ekf"), ("lane_ekf", "models"), ("models", "envs"),
                         ("envs", "latency"), ("latency", "road"), ("road", "io"), ("io", "errors")]:
        assert order[upper] < order[lower], (upper, lower)
    assert "(population)" in flat  # its place is kept before the room exists
    rooms = {p.name for p in (REPO / "plm_highway").iterdir() if (p / "__init__.py").is_file()}
    assert rooms <= set(order), rooms - set(order)


@pytest.fixture(scope="module")
def package_copy(tmp_path_factory) -> Path:
    """The package's Python files, copied, to break on purpose."""
    parent = tmp_path_factory.mktemp("house")
    shutil.copytree(REPO / "plm_highway", parent / "plm_highway",
                    ignore=lambda directory, names: [n for n in names if not (n.endswith(".py") or
                                                                              Path(directory, n).is_dir())])
    return parent


@pytest.mark.parametrize("module, statement, broken", [
    # a lazy import from a lower room into a higher one: the kind the layers exist to catch
    ("road/geometry.py", "def _late():\n    from plm_highway.rollout.cells import run_cells\n", "plm_highway.road"),
    ("rollout/cells.py", "def _late():\n    import plm_highway.evaluation.report\n", "plm_highway.rollout"),
    ("io/formats.py", "from plm_highway import __version__\n", "plm_highway.io"),
    # two rooms on one line stay independent
    ("bench/models.py", "def _late():\n    from plm_highway.sweep import run_sweep\n", "plm_highway.bench"),
    # a module circle inside a room
    ("road/spec.py", "def _late():\n    from plm_highway.road.track import load_track\n", "No cycles"),
])
def test_a_violation_breaks_the_contracts(package_copy, module, statement, broken):
    path = package_copy / "plm_highway" / module
    original = path.read_text(encoding="utf-8")
    try:
        path.write_text(original + "\n\n" + statement, encoding="utf-8")
        result = lint(package_copy)
    finally:
        path.write_text(original, encoding="utf-8")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "BROKEN" in result.stdout and broken in result.stdout


def local_reimports(source: str) -> list[tuple[int, str]]:
    """(line, module) of each import inside a function of a module ``source`` already imports at its top."""
    import ast

    tree = ast.parse(source)
    top = {alias.name for node in tree.body if isinstance(node, ast.Import) for alias in node.names}
    top |= {node.module for node in tree.body if isinstance(node, ast.ImportFrom) and node.module}
    found = []
    for function in ast.walk(tree):
        if not isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(function):
            if isinstance(node, ast.Import):
                found += [(node.lineno, alias.name) for alias in node.names if alias.name in top]
            elif isinstance(node, ast.ImportFrom) and node.module in top:
                found.append((node.lineno, node.module))
    return found


def test_the_reimport_finder_finds_one():
    source = "import json\nfrom a.b import c\n\ndef f():\n    import json\n    from a.b import d\n    import os\n"
    assert local_reimports(source) == [(5, "json"), (6, "a.b")]


def test_no_function_imports_again_what_its_module_imports_at_the_top():
    """A function-local import is for lazy loading (a heavy library the help pages must not import); one of a
    module the file imports at its top anyway only hides the file's dependencies."""
    found = [f"{path.relative_to(REPO)}:{line} {module}" for path in sorted((REPO / "plm_highway").rglob("*.py"))
             for line, module in local_reimports(path.read_text(encoding="utf-8"))]
    assert not found, found
