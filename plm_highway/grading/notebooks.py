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

from pathlib import Path

import nbformat

from plm_highway.grading.course import BEGIN_SOLUTION, annotate, attach_figures, generate_student_versions, validate
from plm_highway.io import file_kind, write_text


def _is_notebook(path: Path) -> bool:
    try:
        return isinstance(nbformat.read(path, as_version=4).cells, list)
    except Exception:  # any unreadable file is not a notebook this build wrote
        return False


# `lessons build` regenerates the kit's own notebooks: it replaces notebooks only, never other files.
NOTEBOOK = file_kind("notebook", "a Jupyter notebook", None, _is_notebook)

BEGIN = BEGIN_SOLUTION  # kept for callers of the old name
DEFAULT_SOLUTIONS = "solutions"
DEFAULT_LESSONS = "lessons"
DEFAULT_FIGURES = "figures/lessons"
KEPT_CELL_METADATA = ("nbgrader", "tags")


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
                    write_text(target, text, NOTEBOOK, overwrite=True)
    return changed

