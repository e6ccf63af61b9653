"""``plm-highway lessons build``: the student notebooks in lessons/ are nbgrader's release of solutions/.

One source: a solution notebook marks each piece students write with nbgrader's markers::

    ### BEGIN SOLUTION
    ...the answer...
    ### END SOLUTION

and carries nbgrader cell metadata (see :mod:`plm_highway.grading.course`). ``build``:

1. normalises each solution: outputs stripped, execution counts cleared, cell ids ``"0"``, ``"1"``, ...,
   cell metadata reduced to ``nbgrader`` and ``tags`` (an instructor's nbgrader metadata is kept as it
   is; a cell without any gets the metadata its content implies), the lesson's target figures embedded
   from ``figures/lessons/``;
2. validates the nbgrader metadata (``ValueError`` naming each wrong cell);
3. runs nbgrader's ``generate_assignment`` on them in a temporary course and writes its release
   notebooks, byte for byte, to lessons/.

``--check`` changes nothing and exits 1 if any file would change.
"""

from __future__ import annotations

import sys
from pathlib import Path

import nbformat

from plm_highway.grading.course import BEGIN_SOLUTION, annotate, attach_figures, generate_student_versions, validate
from plm_highway.io.atomic import write_text_atomic

BEGIN = BEGIN_SOLUTION  # kept for callers of the old name
DEFAULT_SOLUTIONS = "solutions"
DEFAULT_LESSONS = "lessons"
DEFAULT_FIGURES = "figures/lessons"
KEPT_CELL_METADATA = ("nbgrader", "tags")


def configure(parser) -> None:
    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks (nbgrader source)")
    parser.add_argument("--lessons", default=DEFAULT_LESSONS, help="folder the student notebooks are written to")
    parser.add_argument("--figures", default=DEFAULT_FIGURES, help="folder of the lessons' target figures (PNG)")
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if any notebook would change")


def normalise(notebook: nbformat.NotebookNode) -> nbformat.NotebookNode:
    for index, cell in enumerate(notebook.cells):
        cell["id"] = str(index)
        if cell.cell_type == "code":
            cell.outputs = []
            cell.execution_count = None
        cell.metadata = {key: value for key, value in cell.metadata.items() if key in KEPT_CELL_METADATA}
    notebook.metadata = {
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    }
    notebook.nbformat, notebook.nbformat_minor = 4, 5
    return notebook


def _text(notebook: nbformat.NotebookNode) -> str:
    return nbformat.writes(notebook) + "\n"


def normalised_solution(path: Path, figures_dir: Path) -> str:
    """The solution notebook as ``build`` keeps it: normalised, annotated, figures embedded, validated."""
    notebook = normalise(nbformat.read(path, as_version=4))
    annotate(notebook)
    attach_figures(notebook, figures_dir, str(path))
    validate(notebook, str(path))
    return _text(notebook)


def build(solutions_dir: Path, lessons_dir: Path, check: bool = False,
          figures_dir: Path = Path(DEFAULT_FIGURES)) -> list[Path]:
    """Write (or with ``check`` only compare) the normalised solutions and nbgrader's student versions."""
    paths = sorted(Path(solutions_dir).glob("*.ipynb"))
    if not paths:
        raise FileNotFoundError(f"{solutions_dir}: no solution notebooks")
    solutions = {path.name: normalised_solution(path, Path(figures_dir)) for path in paths}
    students = generate_student_versions(solutions)
    changed: list[Path] = []
    for path in paths:
        targets = {path: solutions[path.name], Path(lessons_dir) / path.name: students[path.name]}
        for target, text in targets.items():
            if not target.exists() or target.read_text() != text:
                changed.append(target)
                if not check:
                    write_text_atomic(target, text)
    return changed


def run(args) -> int:
    changed = build(Path(args.solutions), Path(args.lessons), args.check, Path(args.figures))
    for path in changed:
        print(f"{'would change' if args.check else 'wrote'}: {path}")
    if args.check and changed:
        print("lessons are out of date: run 'plm-highway lessons build'", file=sys.stderr)
        return 1
    print("lessons up to date" if not changed else f"{len(changed)} notebook(s) written")
    return 0
