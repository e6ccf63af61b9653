"""The notebook pipeline: solutions/ is nbgrader's source, lessons/ is nbgrader's release, checks are not vacuous."""

from __future__ import annotations

import base64
import os
import re
import shutil
import subprocess
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from plm_highway.grading.checks import MAX_BLOCK_LINES
from plm_highway.grading.course import (
    BEGIN_SOLUTION,
    annotate,
    assignment_id,
    attach_figures,
    check_calls,
    validate,
)
from plm_highway.grading.delegation import REFERENCES
from plm_highway.grading.notebooks import DEFAULT_FIGURES, normalise, normalised_solution

REPO = Path(__file__).resolve().parents[1]
SOLUTIONS = sorted((REPO / "solutions").glob("*.ipynb"))
FIGURES = REPO / DEFAULT_FIGURES
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _notebook(*cells) -> nbformat.NotebookNode:
    notebook = nbformat.v4.new_notebook()
    notebook.cells = [nbformat.v4.new_code_cell(source) if kind == "code" else nbformat.v4.new_markdown_cell(source)
                      for kind, source in cells]
    return notebook


# --- nbgrader metadata ---------------------------------------------------------------------------------------


def test_annotate_marks_solution_grade_and_read_only_cells():
    notebook = _notebook(("markdown", "# Title"), ("code", "def f(x):\n    ### BEGIN SOLUTION\n    return x\n    "
                                                              "### END SOLUTION"),
                         ("code", "lesson3.check_reduction(f)"), ("code", "print(1)"))
    assert annotate(notebook) == [0, 1, 2, 3]
    meta = [cell.metadata.nbgrader for cell in notebook.cells]
    assert [(m["solution"], m["grade"], m["locked"]) for m in meta] == [
        (False, False, True), (True, False, False), (False, True, True), (False, False, True)]
    assert meta[1]["grade_id"] == "f" and meta[2]["grade_id"] == "check_reduction" and meta[2]["points"] == 1
    assert all(m["schema_version"] == 3 for m in meta)
    validate(notebook, "nb")


def test_annotate_and_normalise_keep_an_instructors_metadata():
    notebook = _notebook(("code", "lesson3.check_reduction(f)"), ("code", "x = 1"))
    notebook.cells[0].metadata["nbgrader"] = {"grade": True, "locked": True, "solution": False, "points": 5,
                                              "grade_id": "mine", "schema_version": 3, "task": False}
    notebook.cells[0].metadata["tags"] = ["keep"]
    notebook.cells[0].metadata["collapsed"] = True
    assert annotate(notebook) == [1]
    normalise(notebook)
    assert notebook.cells[0].metadata == {"nbgrader": {"grade": True, "locked": True, "solution": False, "points": 5,
                                                       "grade_id": "mine", "schema_version": 3, "task": False},
                                          "tags": ["keep"]}
    # ... and validation says that 5 points do not match the check's declared 1 point
    with pytest.raises(ValueError, match=r"cell 0: nbgrader points 5 but lesson3.check_reduction is worth 1"):
        validate(notebook, "nb")


@pytest.mark.parametrize(("meta", "source", "message"), [
    ({"solution": False, "locked": True}, "### BEGIN SOLUTION\nx = 1\n### END SOLUTION", "is not a solution cell"),
    ({"solution": True, "locked": False}, "lesson3.check_reduction(f)", "is not a locked grade cell"),
    ({"grade": True, "locked": True, "points": 1}, "lesson3.check_reduction(f)\nlesson3.check_frechet(f)",
     "one check per cell"),
    ({"solution": False, "locked": True}, "x = 1\n### BEGIN HIDDEN TESTS\ny = 2\n### END HIDDEN TESTS",
     "is not a grade cell"),
    ({"solution": False, "locked": False}, "x = 1", "neither a solution, a grade nor a read-only cell"),
    ({"solution": False, "locked": True, "schema_version": 1}, "x = 1", "schema_version 1"),
])
def test_validate_names_the_wrong_cell(meta, source, message):
    notebook = _notebook(("code", "def f():\n    ### BEGIN SOLUTION\n    pass\n    ### END SOLUTION"), ("code", source))
    annotate(notebook)
    full = {"grade": False, "solution": False, "locked": False, "task": False, "schema_version": 3, "grade_id": "x"}
    notebook.cells[1].metadata["nbgrader"] = {**full, **meta}
    with pytest.raises(ValueError, match=re.escape(message)):
        validate(notebook, "nb.ipynb")


def test_validate_refuses_a_notebook_without_solution_regions():
    notebook = _notebook(("code", "x = 1"))
    annotate(notebook)
    with pytest.raises(ValueError, match="student copy would be the solution"):
        validate(notebook, "nb.ipynb")


def test_attach_figures_reports_a_missing_png(tmp_path):
    notebook = _notebook(("markdown", "![target](attachment:missing.png)"))
    with pytest.raises(FileNotFoundError, match="missing.png"):
        attach_figures(notebook, tmp_path, "nb.ipynb")


# --- solutions/ and lessons/ ------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_solution_is_normalised_annotated_and_valid(path):
    assert normalised_solution(path, FIGURES) == path.read_text(), f"run 'plm-highway lessons build': {path.name}"


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_solution_and_lesson_are_stripped_with_stable_ids(path):
    for notebook_path in (path, REPO / "lessons" / path.name):
        notebook = nbformat.read(notebook_path, as_version=4)
        assert [cell["id"] for cell in notebook.cells] == [str(i) for i in range(len(notebook.cells))]
        for cell in notebook.cells:
            if cell.cell_type == "code":
                assert cell.outputs == [] and cell.execution_count is None
    lesson_text = (REPO / "lessons" / path.name).read_text()
    assert BEGIN_SOLUTION not in lesson_text and "HIDDEN TESTS" not in lesson_text
    assert "raise NotImplementedError()" in lesson_text
    assert "### BEGIN HIDDEN TESTS" in path.read_text(), f"{path.name}: no hidden test cases"


@pytest.mark.skipif(shutil.which("nbgrader") is None, reason="nbgrader's command line is not installed")
def test_lessons_are_byte_identical_to_nbgrader_generate_assignment(tmp_path):
    """An instructor's course: solutions as nbgrader's source, ``nbgrader generate_assignment`` for them all.

    One command for every assignment (nbgrader reads the assignment name as a pattern): each nbgrader
    command spends seconds starting up and creating the gradebook, more than generating a lesson."""
    for path in SOLUTIONS:
        folder = tmp_path / "source" / assignment_id(path.name)
        folder.mkdir(parents=True)
        shutil.copyfile(path, folder / path.name)
    (tmp_path / "nbgrader_config.py").write_text('c = get_config()\nc.CourseDirectory.course_id = "plm_highway"\n')
    subprocess.run(["nbgrader", "generate_assignment", "*", "--force"], cwd=tmp_path, check=True, capture_output=True,
                   text=True, timeout=300)
    assert sorted(p.name for p in (tmp_path / "release").iterdir()) == [assignment_id(p.name) for p in SOLUTIONS]
    for path in SOLUTIONS:
        released = tmp_path / "release" / assignment_id(path.name) / path.name
        assert released.read_bytes() == (REPO / "lessons" / path.name).read_bytes(), (
            f"lessons/{path.name} differs from nbgrader's release: run 'plm-highway lessons build'")


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_lesson_shows_its_target_figure(path):
    figure = FIGURES / (path.stem + ".png")
    assert figure.is_file() and figure.stat().st_size < 150_000
    for notebook_path in (path, REPO / "lessons" / path.name):
        intro = nbformat.read(notebook_path, as_version=4).cells[0]
        assert f"(attachment:{figure.name})" in intro.source
        assert base64.b64decode(intro.attachments[figure.name]["image/png"]) == figure.read_bytes()


def _code_patterns(name: str) -> list[re.Pattern]:
    word = re.escape(name)
    return [re.compile(rf"\b{word}\s*\("), re.compile(rf"import[^\n]*\b{word}\b"), re.compile(rf"\.{word}\b"),
            re.compile(rf"`{word}`")]


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_lesson_text_names_no_reference_implementation(path):
    lesson = "lesson" + str(int(path.name[:2]))
    notebook = nbformat.read(REPO / "lessons" / path.name, as_version=4)
    text = "\n".join(cell.source for cell in notebook.cells)
    own = {reference.exercise.split(".", 1)[1] for reference in REFERENCES if reference.exercise.startswith(lesson)}
    for reference in REFERENCES:
        if not reference.exercise.startswith(lesson + "."):
            continue
        name = reference.name.split(":")[1].split(".")[-1]
        if name in own:
            continue  # the student's own function has this name
        hits = [pattern.pattern for pattern in _code_patterns(name) if pattern.search(text)]
        assert not hits, f"{path.name} names the reference implementation {reference.name} ({hits})"


# --- the stubs fail every check, with a short block ------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.name)
def test_every_check_fails_on_the_student_stub_with_a_short_block(path):
    """Also why nbgrader gives every lesson's untouched notebook zero (tests/test_lessons_nbgrader.py grades one)."""
    lesson = nbformat.read(REPO / "lessons" / path.name, as_version=4)
    os.environ["PLM_FAST"] = "1"
    NotebookClient(lesson, timeout=600, allow_errors=True, kernel_name="python3",
                   resources={"metadata": {"path": str(REPO / "lessons")}}).execute()
    check_cells = [cell for cell in lesson.cells if cell.cell_type == "code" and check_calls(cell.source)]
    assert check_cells, f"{path.name}: no graded check calls found"
    for cell in check_cells:
        errors = [out for out in cell.outputs if out.output_type == "error"]
        passed = [out for out in cell.outputs if "PASSED" in str(out.get("text", ""))]
        assert errors and not passed, f"{path.name} cell {cell['id']}: a check passed on the stub:\n{cell.source}"
        error = errors[0]
        assert error.ename == "CheckFailed", f"{path.name} cell {cell['id']}: failed with {error.ename}"
        block = [ANSI.sub("", line) for line in error.traceback]
        assert len(block) <= MAX_BLOCK_LINES + 1, "\n".join(block)
        assert block[0].startswith("FAILED check_") and "not implemented yet" in block[1], "\n".join(block)
        assert not any("plm_highway/grading" in line or "File " in line for line in block), "\n".join(block)

