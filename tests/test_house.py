"""House rules a test can hold: library code never imports the command line; no function re-imports what its module
imports at the top; one definition of each shared concept."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "plm_highway"


def _imported_modules(path: Path) -> set[str]:
    """Every module a file imports, at any depth (lazy imports inside functions count too)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _library_files() -> list[Path]:
    return [path for path in sorted(PACKAGE.rglob("*.py"))
            if "cli" not in path.relative_to(PACKAGE).parts[:1] and path.name != "__main__.py"]


def _local_reimports(path: Path) -> list[str]:
    """``module (line)`` for each import inside a function of a module the file already imports at its top."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    top = {alias.name for node in tree.body if isinstance(node, ast.Import) for alias in node.names}
    top |= {node.module for node in tree.body if isinstance(node, ast.ImportFrom) and node.module}
    found = []
    for function in ast.walk(tree):
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(function):
                names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                         else [node.module] if isinstance(node, ast.ImportFrom) and node.module else [])
                found += [f"{name} (line {node.lineno})" for name in names if name in top]
    return found


def test_no_function_re_imports_what_its_module_imports_at_the_top():
    offenders = {str(path.relative_to(PACKAGE)): _local_reimports(path) for path in sorted(PACKAGE.rglob("*.py"))}
    assert {file: found for file, found in offenders.items() if found} == {}


def test_the_re_import_walk_sees_a_re_import(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("import numpy as np\nfrom os import path\n\ndef f():\n    import numpy\n    from os import sep\n"
                      "    import json\n")
    assert _local_reimports(sample) == ["numpy (line 5)", "os (line 6)"]


LAZY_REASON = re.compile(r"#.*\b(lazy|lazily|optional|cycle|circular)\b", re.IGNORECASE)


def _unexplained_local_imports(path: Path) -> list[str]:
    """``function (line)`` for each function importing inside its body with no comment there saying why."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    found = []
    for function in ast.walk(ast.parse(source, filename=str(path))):
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)) and any(
                isinstance(node, (ast.Import, ast.ImportFrom)) for node in ast.walk(function)):
            if not LAZY_REASON.search("\n".join(lines[function.lineno - 1:function.end_lineno])):
                found.append(f"{function.name} (line {function.lineno})")
    return found


def test_library_code_imports_inside_a_function_only_for_a_stated_reason():
    # The command line is lazy by design (--help imports no torch); elsewhere an import inside a function needs a
    # reason (an optional or slow dependency, an import cycle) written beside it.
    offenders = {str(path.relative_to(PACKAGE)): _unexplained_local_imports(path) for path in _library_files()}
    assert {file: found for file, found in offenders.items() if found} == {}


def test_the_reason_walk_sees_an_unexplained_import(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    import json\n\n\ndef g():\n    import ray  # lazy: optional\n")
    assert _unexplained_local_imports(sample) == ["f (line 1)"]


def test_library_modules_never_import_the_command_line():
    offenders = {str(path.relative_to(PACKAGE)): sorted(name for name in _imported_modules(path)
                                                          if name == "plm_highway.cli" or name.startswith("plm_highway.cli."))
                 for path in _library_files()}
    assert _library_files(), "no library files found: the walk itself is broken"
    assert {file: names for file, names in offenders.items() if names} == {}


def test_the_walk_sees_lazy_imports(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    from plm_highway.cli import main\n    import plm_highway.cli._common\n")
    assert {"plm_highway.cli", "plm_highway.cli.main", "plm_highway.cli._common"} <= _imported_modules(sample)


def test_no_library_module_defines_command_line_entry_points():
    """configure(parser)/run(args) pairs belong to plm_highway/cli adapters, not to library rooms."""
    pairs = []
    for path in _library_files():
        functions = {node.name for node in ast.parse(path.read_text(encoding="utf-8")).body
                     if isinstance(node, ast.FunctionDef)}
        if {"configure", "run"} <= functions:
            pairs.append(str(path.relative_to(PACKAGE)))
    assert pairs == []


def test_one_definition_of_each_shared_concept():
    """A mean with its confidence interval, seeds as the commands take them, driving a list of runs and resolving a
    track each have one definition, which every caller uses (no second copy with its own behaviour)."""
    concepts = {"mean_ci": [], "parse_seeds": [], "run_cells": [], "resolve_track": [], "t quantile": []}
    for path in sorted(PACKAGE.rglob("*.py")):
        where = str(path.relative_to(PACKAGE))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name in concepts:
                concepts[node.name].append(where)
            elif (isinstance(node, ast.Attribute) and node.attr == "ppf" and isinstance(node.value, ast.Attribute)
                  and node.value.attr == "t"):  # scipy.stats.t.ppf: a Student-t interval computed here
                concepts["t quantile"].append(where)
    assert concepts == {"mean_ci": ["metrics/intervals.py"], "parse_seeds": ["rollout/seeds.py"],
                        "run_cells": ["rollout/cells.py"], "resolve_track": ["road/track.py"],
                        "t quantile": ["metrics/intervals.py"]}
