"""The lessons as an nbgrader course: cell metadata, the student versions, autograding.

nbgrader is the grading pipeline. A solution notebook in ``solutions/`` is nbgrader's *source*
version: every cell carries ``metadata.nbgrader`` (schema version 3):

* a code cell with ``### BEGIN SOLUTION`` / ``### END SOLUTION`` regions is an *autograded answer*
  (``solution: true``; its ``grade_id`` is the first function or class it defines);
* a code cell that calls one graded check, ``lessonN.check_x(...)``, is a locked *autograder test*
  (``grade: true``, ``locked: true``, ``points`` equal to the check's ``@graded(points=...)``). It may
  hold ``### BEGIN HIDDEN TESTS`` / ``### END HIDDEN TESTS``: further seeded cases that students never
  see and autograding restores;
* every other cell is *read-only* (``locked: true``).

:func:`annotate` adds that metadata to cells that have none (it never changes a cell that has some),
:func:`validate` checks it, and :func:`generate_student_versions` runs nbgrader's own
``generate_assignment`` on the solutions in a temporary course: ``lessons/`` holds its output byte for
byte. :func:`grade_submissions` autogrades students' notebooks with nbgrader in a temporary course for
an instructor who has none set up.
"""

from __future__ import annotations

import ast
import base64
import contextlib
import importlib
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import nbformat

from plm_highway.errors import BadInput
from plm_highway.io import file_kind, write_csv
from plm_highway.io.bounded import json_depth

BEGIN_SOLUTION = "### BEGIN SOLUTION"
END_SOLUTION = "### END SOLUTION"
BEGIN_HIDDEN = "### BEGIN HIDDEN TESTS"
END_HIDDEN = "### END HIDDEN TESTS"
CHECK_CALL = re.compile(r"\b(lesson\d+)\.(check_\w+)\(")
ATTACHMENT = re.compile(r"\(attachment:([\w.-]+\.png)\)")
SCHEMA_VERSION = 3
COURSE_ID = "plm_highway"
MAX_SUBMISSION_BYTES = 50_000_000  # a lesson notebook with outputs is ~1 MB; larger is not a submission
MAX_NOTEBOOK_DEPTH = 64  # a notebook's JSON nests about 6 deep (widget state a little more)
CELL_TIMEOUT_S = 900


# --- Metadata -----------------------------------------------------------------------------------------------


def check_calls(source: str) -> list[tuple[str, str]]:
    """(lesson module, check name) of every graded check the cell calls."""
    return CHECK_CALL.findall(source)


def check_points(module: str, check: str) -> int:
    """The points a check declares with ``@graded(points=...)``."""
    function = getattr(importlib.import_module(f"plm_highway.grading.{module}"), check, None)
    points = getattr(function, "points", None)
    if points is None:
        raise ValueError(f"plm_highway.grading.{module}.{check} is not a graded check (no @graded points)")
    return int(points)


def _first_definition(source: str) -> str | None:
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return None
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            return node.name
    return None


def annotate(notebook: nbformat.NotebookNode) -> list[int]:
    """Give every cell without ``metadata.nbgrader`` the metadata its content implies; returns their indices.

    Cells that already have nbgrader metadata (an instructor's choice) are left exactly as they are.
    """
    used = {cell.metadata["nbgrader"].get("grade_id") for cell in notebook.cells if "nbgrader" in cell.metadata}
    added = []
    for index, cell in enumerate(notebook.cells):
        if "nbgrader" in cell.metadata:
            continue
        meta = {"grade": False, "locked": True, "schema_version": SCHEMA_VERSION, "solution": False, "task": False}
        calls = check_calls(cell.source) if cell.cell_type == "code" else []
        if cell.cell_type == "code" and BEGIN_SOLUTION in cell.source:
            meta.update(locked=False, solution=True)
            base = _first_definition(cell.source.replace(BEGIN_SOLUTION, "").replace(END_SOLUTION, "")) or "answer"
        elif calls:
            module, check = calls[0]
            meta.update(grade=True, points=check_points(module, check))
            base = check
        else:
            base = f"cell_{index}"
        grade_id, suffix = base, 2
        while grade_id in used:
            grade_id, suffix = f"{base}_{suffix}", suffix + 1
        used.add(grade_id)
        meta["grade_id"] = grade_id
        cell.metadata["nbgrader"] = dict(sorted(meta.items()))
        added.append(index)
    return added


def validate(notebook: nbformat.NotebookNode, where: str) -> None:
    """Raise ``ValueError`` naming every cell whose nbgrader metadata does not fit its content."""
    # lazy here and below: nbgrader (with alembic, traitlets) costs seconds to import, only when grading runs
    from nbgrader.nbgraderformat import MetadataValidator, SchemaTooNewError, SchemaTooOldError, ValidationError

    problems = []
    for index, cell in enumerate(notebook.cells):
        meta = cell.metadata.get("nbgrader")
        at = f"{where}, cell {index}"
        if meta is None:
            problems.append(f"{at}: no nbgrader metadata (run 'plm-highway lessons build' to add it)")
            continue
        if meta.get("schema_version") != SCHEMA_VERSION:
            problems.append(f"{at}: nbgrader schema_version {meta.get('schema_version')!r}, expected {SCHEMA_VERSION}")
        has_solution = BEGIN_SOLUTION in cell.source
        if has_solution and not meta.get("solution"):
            problems.append(f"{at}: has a '{BEGIN_SOLUTION}' region but is not a solution cell")
        if BEGIN_HIDDEN in cell.source and not meta.get("grade"):
            problems.append(f"{at}: has a '{BEGIN_HIDDEN}' region but is not a grade cell")
        calls = check_calls(cell.source) if cell.cell_type == "code" else []
        if calls:
            names = sorted({f"{module}.{check}" for module, check in calls})
            if len(names) > 1:
                problems.append(f"{at}: calls {len(names)} different checks {names}; one check per cell")
            module, check = calls[0]
            if not (meta.get("grade") and meta.get("locked")):
                problems.append(f"{at}: calls {module}.{check} but is not a locked grade cell")
            else:
                try:
                    points = check_points(module, check)
                except ValueError as error:
                    problems.append(f"{at}: {error}")
                else:
                    if float(meta.get("points", -1)) != points:
                        problems.append(f"{at}: nbgrader points {meta.get('points')!r} but {module}.{check} is "
                                        f"worth {points}")
        elif meta.get("grade") and cell.cell_type == "code":
            problems.append(f"{at}: a grade cell that calls no lessonN.check_...() function")
        if not (meta.get("solution") or meta.get("grade") or meta.get("task") or meta.get("locked")):
            problems.append(f"{at}: neither a solution, a grade nor a read-only cell")
    try:
        MetadataValidator().validate_nb(nbformat.from_dict(notebook))
    except (ValidationError, SchemaTooOldError, SchemaTooNewError) as error:
        problems.append(f"{where}: nbgrader rejects the metadata: {error}")
    if not any(BEGIN_SOLUTION in cell.source for cell in notebook.cells if cell.cell_type == "code"):
        problems.append(f"{where}: no '{BEGIN_SOLUTION}' region, so the student copy would be the solution")
    if problems:
        raise ValueError("invalid nbgrader metadata:\n  " + "\n  ".join(problems))


def attach_figures(notebook: nbformat.NotebookNode, figures_dir: Path, where: str) -> None:
    """Embed each ``![..](attachment:NAME.png)`` of a markdown cell from ``figures_dir/NAME.png``."""
    for index, cell in enumerate(notebook.cells):
        if cell.cell_type != "markdown":
            continue
        names = ATTACHMENT.findall(cell.source)
        attachments = {}
        for name in names:
            path = Path(figures_dir) / name
            if not path.is_file():
                raise FileNotFoundError(f"{where}, cell {index}: {path} not found (run 'plm-highway lessons "
                                        f"figures' to make the lesson figures)")
            attachments[name] = {"image/png": base64.b64encode(path.read_bytes()).decode("ascii")}
        if attachments:
            cell["attachments"] = attachments
        elif "attachments" in cell:
            del cell["attachments"]


# --- A temporary nbgrader course ------------------------------------------------------------------------------


def assignment_id(notebook_name: str) -> str:
    """One nbgrader assignment per lesson, named after its notebook ("01_latency_zigzag")."""
    return Path(notebook_name).stem


@contextlib.contextmanager
def temporary_course(sources: Mapping[str, str]) -> Iterator[Path]:
    """A course directory with ``source/<assignment>/<name>`` for each solution text, and its gradebook."""
    with tempfile.TemporaryDirectory(prefix="plm_highway_course_") as tmp:
        root = Path(tmp)
        for name, text in sources.items():
            folder = root / "source" / assignment_id(name)
            folder.mkdir(parents=True)
            (folder / name).write_text(text)  # inside our own temporary course, not a user path
        _create_gradebook(root)
        yield root


def _db_url(root: Path) -> str:
    return f"sqlite:///{root / 'gradebook.db'}"


def gradebook_revision() -> str | None:
    """The alembic revision nbgrader stamps a new gradebook with: the head of its own migration scripts."""
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    from alembic.script import ScriptDirectory
    from alembic.util import CommandError
    from nbgrader.dbutil import ALEMBIC_DIR

    try:
        return ScriptDirectory(ALEMBIC_DIR).get_current_head()
    except CommandError:  # several heads: leave the choice to nbgrader
        return None


def _create_gradebook(root: Path) -> None:
    """Create the course's gradebook with nbgrader's ``Gradebook``, reading its revision in this process.

    A new gradebook is stamped with the head revision of nbgrader's migration scripts, which nbgrader reads
    by running ``alembic heads`` in a subprocess; that subprocess imports nbgrader afresh, about 4 s of CPU,
    more than generating all five student versions. :func:`gradebook_revision` reads the same scripts here;
    everything else is nbgrader's own. Where the revision cannot be read, nbgrader creates the gradebook
    as usual when its first converter runs.
    """
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    import nbgrader.api

    revision = gradebook_revision()
    if revision is None or not callable(getattr(nbgrader.api, "get_alembic_version", None)):
        return
    in_a_subprocess = nbgrader.api.get_alembic_version
    nbgrader.api.get_alembic_version = lambda: revision
    try:
        with nbgrader.api.Gradebook(_db_url(root), COURSE_ID):
            pass
    finally:
        nbgrader.api.get_alembic_version = in_a_subprocess


def _config(root: Path, timeout_s: int = CELL_TIMEOUT_S):
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    from traitlets.config import Config

    config = Config()
    config.CourseDirectory.root = str(root)
    config.CourseDirectory.course_id = COURSE_ID
    config.CourseDirectory.db_url = _db_url(root)
    config.Execute.timeout = timeout_s
    config.Exchange.root = str(root / "exchange")
    return config


def _quiet_nbgrader_logs() -> None:
    for name in ("traitlets", "nbgrader", "GenerateAssignment", "Autograde"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _run_converter(converter_class, root: Path, assignment: str, student: str = ".", timeout_s: int = CELL_TIMEOUT_S):
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    from nbgrader.coursedir import CourseDirectory

    _quiet_nbgrader_logs()
    config = _config(root, timeout_s)
    coursedir = CourseDirectory(config=config)
    coursedir.assignment_id = assignment
    coursedir.student_id = student
    converter = converter_class(coursedir=coursedir, config=config)
    converter.force = True
    converter.log.setLevel(logging.ERROR)
    try:
        converter.start()
    except Exception as error:  # nbgrader raises NbGraderException after logging the cause
        raise RuntimeError(f"nbgrader {converter_class.__name__} failed for {assignment} ({student}): {error}") from error


def generate_student_versions(sources: Mapping[str, str]) -> dict[str, str]:
    """nbgrader ``generate_assignment`` of each solution text: {notebook name: student notebook text}."""
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    from nbgrader.converters import GenerateAssignment

    released = {}
    with temporary_course(sources) as root:
        for name in sources:
            _run_converter(GenerateAssignment, root, assignment_id(name))
            released[name] = (root / "release" / assignment_id(name) / name).read_text()
    return released


# --- Grading submissions -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LessonScore:
    """One student's autograded score on one lesson."""

    student: str
    lesson: str
    score: float
    max_score: float
    failed_checks: tuple[str, ...]

    def row(self) -> list[str]:
        return [self.student, self.lesson, f"{self.score:g}", f"{self.max_score:g}", ";".join(self.failed_checks)]


SCORE_COLUMNS = ["student", "lesson", "score", "max_score", "failed_checks"]
SCORES_CSV = file_kind("lesson-scores", "a lesson scores table", SCORE_COLUMNS)


def find_submissions(submissions_dir: Path, lesson_names: list[str]) -> dict[str, dict[str, Path]]:
    """``SUBMISSIONS_DIR/<student>/<lesson>.ipynb`` -> {student: {lesson notebook name: path}}.

    A lesson notebook is recognised by its file name (one of ``lesson_names``); other files are ignored.
    """
    submissions_dir = Path(submissions_dir)
    if not submissions_dir.is_dir():
        raise ValueError(f"{submissions_dir}: not a directory (expected SUBMISSIONS_DIR/<student>/<lesson>.ipynb)")
    found: dict[str, dict[str, Path]] = {}
    for student_dir in sorted(p for p in submissions_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if not re.fullmatch(r"[\w.@+-]+", student_dir.name):
            raise ValueError(f"{student_dir}: a student folder name may hold letters, digits and . _ @ + - only")
        for name in lesson_names:
            path = student_dir / name
            if path.is_file():
                if path.stat().st_size > MAX_SUBMISSION_BYTES:
                    raise ValueError(f"{path}: {path.stat().st_size} bytes, more than the "
                                     f"{MAX_SUBMISSION_BYTES} a lesson notebook can be")
                _check_nesting(path)
                found.setdefault(student_dir.name, {})[name] = path
    if not found:
        raise ValueError(f"{submissions_dir}: no submissions; expected <student>/<lesson>.ipynb with a lesson "
                         f"name from {lesson_names}")
    return found


def _check_nesting(path: Path) -> None:
    """Refuse a notebook nested deeper than any notebook is before nbformat's recursive parser reads it
    (200,000 levels crash it); anything else unreadable is left to the grader, which scores it zero."""
    depth, _ = json_depth(path.read_bytes().decode("utf-8", "replace"))
    if depth > MAX_NOTEBOOK_DEPTH:
        raise BadInput(f"{path}: brackets nested {depth} deep; a lesson notebook needs at most {MAX_NOTEBOOK_DEPTH} "
                       "(nesting limit)")


@contextlib.contextmanager
def _environment(**values: str) -> Iterator[None]:
    old = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in old.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def grade_submissions(solutions_dir: Path, submissions_dir: Path, fast: bool = True,
                      timeout_s: int = CELL_TIMEOUT_S) -> list[LessonScore]:
    """Autograde every ``SUBMISSIONS_DIR/<student>/<lesson>.ipynb`` with nbgrader, in a temporary course.

    The course's source versions are the (validated) solution notebooks; nbgrader restores the
    locked cells and the hidden tests before it runs a submission, so a student cannot change a
    check. ``fast`` runs the notebooks with ``PLM_FAST=1`` (the graded checks do not depend on it).
    """
    # lazy: nbgrader (and its alembic, traitlets) takes seconds to import; only building and grading need it
    from nbgrader.api import Gradebook
    from nbgrader.converters import Autograde, GenerateAssignment

    sources = solution_sources(Path(solutions_dir))
    submissions = find_submissions(Path(submissions_dir), sorted(sources))
    scores = []
    with temporary_course(sources) as root, _environment(PLM_FAST="1" if fast else "0",
                                                          MPLBACKEND="Agg", SDL_VIDEODRIVER="offscreen"):
        for name in sorted({name for lessons in submissions.values() for name in lessons}):
            _run_converter(GenerateAssignment, root, assignment_id(name))
        for student, lessons in submissions.items():
            for name, path in sorted(lessons.items()):
                folder = root / "submitted" / student / assignment_id(name)
                folder.mkdir(parents=True)
                shutil.copyfile(path, folder / name)
                _run_converter(Autograde, root, assignment_id(name), student, timeout_s)
        with Gradebook(_db_url(root), COURSE_ID) as gradebook:
            for student, lessons in submissions.items():
                for name in sorted(lessons):
                    submission = gradebook.find_submission(assignment_id(name), student)
                    failed = tuple(grade.name for notebook in submission.notebooks for grade in notebook.grades
                                   if grade.max_score > 0 and (grade.score or 0) < grade.max_score)
                    scores.append(LessonScore(student, assignment_id(name), float(submission.score),
                                              float(submission.max_score), failed))
    return scores


def solution_sources(solutions_dir: Path) -> dict[str, str]:
    """{notebook name: text} of the solution notebooks, each validated."""
    paths = sorted(Path(solutions_dir).glob("*.ipynb"))
    if not paths:
        raise ValueError(f"{solutions_dir}: no solution notebooks (*.ipynb)")
    sources = {}
    for path in paths:
        text = path.read_text()
        validate(nbformat.reads(text, as_version=4), str(path))
        sources[path.name] = text
    return sources


def write_scores_csv(scores: list[LessonScore], path: Path, overwrite: bool = False) -> None:
    """Write the scores; an existing file is replaced only with ``overwrite`` and only if it is a scores table."""

    write_csv(path, SCORE_COLUMNS, [score.row() for score in scores], SCORES_CSV, overwrite=overwrite)
