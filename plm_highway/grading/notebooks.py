"""``plm-highway lessons build``: write the student notebooks in lessons/ from solutions/.

One source: a solution notebook marks each piece students write with nbgrader's markers::

    ### BEGIN SOLUTION
    ...the answer...
    ### END SOLUTION

The student copy replaces each marked region with ``raise NotImplementedError(...)`` at the
same indentation. Both copies are normalised: outputs stripped, execution counts cleared and
cell ids ``"0"``, ``"1"``, ... so that regenerating is idempotent and diffs stay textual.
``--check`` changes nothing and exits 1 if any file would change.
"""

from __future__ import annotations

import sys
from pathlib import Path

import nbformat

from plm_highway.io import file_kind, write_text


def _is_notebook(path: Path) -> bool:
    try:
        return isinstance(nbformat.read(path, as_version=4).cells, list)
    except Exception:  # any unreadable file is not a notebook this build wrote
        return False


# `lessons build` regenerates the kit's own notebooks: it replaces notebooks only, never other files.
NOTEBOOK = file_kind("notebook", "a Jupyter notebook", None, _is_notebook)

BEGIN = "### BEGIN SOLUTION"
END = "### END SOLUTION"
STUB = 'raise NotImplementedError("your code here")'


def configure(parser) -> None:
    parser.add_argument("--solutions", default="solutions", help="folder of solution notebooks (the single source)")
    parser.add_argument("--lessons", default="lessons", help="folder of student notebooks to write")
    parser.add_argument("--check", action="store_true", help="exit 1 if any notebook would change")


def strip_solutions(source: str, where: str = "cell") -> str:
    """Replace every BEGIN/END SOLUTION region with a NotImplementedError stub."""
    lines = source.split("\n")
    out: list[str] = []
    inside = False
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if stripped == BEGIN:
            if inside:
                raise ValueError(f"{where}, line {number}: nested '{BEGIN}'")
            inside = True
            out.append(line[: len(line) - len(line.lstrip())] + STUB)
        elif stripped == END:
            if not inside:
                raise ValueError(f"{where}, line {number}: '{END}' without '{BEGIN}'")
            inside = False
        elif not inside:
            out.append(line)
    if inside:
        raise ValueError(f"{where}: '{BEGIN}' is never closed")
    return "\n".join(out)


def normalise(notebook: nbformat.NotebookNode) -> nbformat.NotebookNode:
    for index, cell in enumerate(notebook.cells):
        cell["id"] = str(index)
        if cell.cell_type == "code":
            cell.outputs = []
            cell.execution_count = None
        cell.metadata = {key: value for key, value in cell.metadata.items() if key in ("tags",)}
    notebook.metadata = {
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    }
    notebook.nbformat, notebook.nbformat_minor = 4, 5
    return notebook


def student_version(solution: nbformat.NotebookNode, name: str) -> nbformat.NotebookNode:
    student = nbformat.from_dict(solution)
    for index, cell in enumerate(student.cells):
        if cell.cell_type == "code":
            cell.source = strip_solutions(cell.source, f"{name}, cell {index}")
    return normalise(student)


def _text(notebook: nbformat.NotebookNode) -> str:
    return nbformat.writes(notebook) + "\n"


def build(solutions_dir: Path, lessons_dir: Path, check: bool = False) -> list[Path]:
    """Write (or with ``check`` only compare) normalised solutions and their student copies."""
    sources = sorted(Path(solutions_dir).glob("*.ipynb"))
    if not sources:
        raise FileNotFoundError(f"{solutions_dir}: no solution notebooks")
    changed: list[Path] = []
    for path in sources:
        solution = normalise(nbformat.read(path, as_version=4))
        if not any(BEGIN in cell.source for cell in solution.cells if cell.cell_type == "code"):
            raise ValueError(f"{path}: no '{BEGIN}' region, so the student copy would be the solution")
        targets = {path: _text(solution),
                   Path(lessons_dir) / path.name: _text(student_version(solution, str(path)))}
        for target, text in targets.items():
            if not target.exists() or target.read_text() != text:
                changed.append(target)
                if not check:
                    write_text(target, text, NOTEBOOK, overwrite=True)
    return changed


def run(args) -> int:
    changed = build(Path(args.solutions), Path(args.lessons), args.check)
    for path in changed:
        print(f"{'would change' if args.check else 'wrote'}: {path}")
    if args.check and changed:
        print("lessons are out of date: run 'plm-highway lessons build'", file=sys.stderr)
        return 1
    print("lessons up to date" if not changed else f"{len(changed)} notebook(s) written")
    return 0


