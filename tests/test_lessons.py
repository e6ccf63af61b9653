"""The notebook pipeline: one source, idempotent generation, and checks that are not vacuous."""

from __future__ import annotations

import os
import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from plm_highway.grading.notebooks import BEGIN, build, strip_solutions

REPO = Path(__file__).resolve().parents[1]
SOLUTIONS = sorted((REPO / "solutions").glob("*.ipynb"))
CHECK_CALL = re.compile(r"lesson\d+\.check_\w+\(")


def test_strip_solutions_keeps_indentation_and_code_outside_markers():
    source = "def f(x):\n    y = 1\n    ### BEGIN SOLUTION\n    return x + y\n    ### END SOLUTION\nprint(f)"
    assert strip_solutions(source) == 'def f(x):\n    y = 1\n    raise NotImplementedError("your code here")\nprint(f)'


@pytest.mark.parametrize("source", ["### BEGIN SOLUTION\nx = 1", "x = 1\n### END SOLUTION",
                                    "### BEGIN SOLUTION\n### BEGIN SOLUTION\n### END SOLUTION"])
def test_unbalanced_markers_are_errors(source):
    with pytest.raises(ValueError, match="SOLUTION"):
        strip_solutions(source, "nb, cell 3")


def test_regenerating_lessons_changes_nothing():
    changed = build(REPO / "solutions", REPO / "lessons", check=True)
    assert changed == [], f"run 'plm-highway lessons build': {changed}"


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_solution_and_lesson_are_stripped_with_stable_ids(path):
    for notebook_path in (path, REPO / "lessons" / path.name):
        notebook = nbformat.read(notebook_path, as_version=4)
        assert [cell["id"] for cell in notebook.cells] == [str(i) for i in range(len(notebook.cells))]
        for cell in notebook.cells:
            if cell.cell_type == "code":
                assert cell.outputs == [] and cell.execution_count is None
    lesson_text = (REPO / "lessons" / path.name).read_text()
    assert BEGIN not in lesson_text and "NotImplementedError" in lesson_text


@pytest.mark.slow
@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_every_check_fails_on_the_student_stub(path):
    lesson = nbformat.read(REPO / "lessons" / path.name, as_version=4)
    os.environ["PLM_FAST"] = "1"
    NotebookClient(lesson, timeout=600, allow_errors=True, kernel_name="python3",
                   resources={"metadata": {"path": str(REPO / "lessons")}}).execute()
    check_cells = [cell for cell in lesson.cells if cell.cell_type == "code" and CHECK_CALL.search(cell.source)]
    assert check_cells, f"{path.name}: no graded check calls found"
    for cell in check_cells:
        assert len(CHECK_CALL.findall(cell.source)) == 1, f"{path.name} cell {cell['id']}: one check per cell"
        errors = [out for out in cell.outputs if out.output_type == "error"]
        passed = [out for out in cell.outputs if "PASSED" in str(out.get("text", ""))]
        assert errors and not passed, f"{path.name} cell {cell['id']}: a check passed on the stub:\n{cell.source}"
        assert errors[0].ename in ("CheckFailed", "AssertionError"), (
            f"{path.name} cell {cell['id']}: the check failed with {errors[0].ename}, not a graded failure")
