"""nbgrader grades the lessons end to end: every lesson's worked solution gets full marks; for one lesson the
untouched student notebook gets zero and a partly done one the points in between. Runs the instructor's
command (``plm-highway lessons grade``), which autogrades with nbgrader in a temporary course.

Each graded notebook is a kernel running a lesson top to bottom, so only what this module alone shows is
graded: the solutions (nbgrader restores the locked cells and hidden tests, and every check passes) and, for
the cheapest lesson, that nbgrader turns failing grade cells into zero and partial points. That every other
lesson's student notebook scores zero follows from tests/test_lessons.py, which runs each of them and finds
every grade cell failing with ``CheckFailed``: a grade cell whose visible check fails scores nothing, its
hidden tests coming after it.
"""

from __future__ import annotations

import contextlib
import csv
from pathlib import Path

import nbformat
import pytest

from plm_highway import cli
from plm_highway.grading.course import SCORE_COLUMNS, find_submissions, temporary_course, write_scores_csv

REPO = Path(__file__).resolve().parents[1]
SOLUTIONS = sorted((REPO / "solutions").glob("*.ipynb"))


def _solution_cells(path: Path) -> dict[str, str]:
    cells = nbformat.read(path, as_version=4).cells
    return {cell.metadata.nbgrader["grade_id"]: cell.source for cell in cells if cell.metadata.nbgrader["solution"]}


def _submission(name: str, answered: int | None) -> str:
    """The student's notebook with its first ``answered`` solution cells filled in (None: all)."""
    student = nbformat.read(REPO / "lessons" / name, as_version=4)
    answers = _solution_cells(REPO / "solutions" / name)
    solution_cells = [cell for cell in student.cells if cell.metadata.nbgrader["solution"]]
    for cell in solution_cells[: len(solution_cells) if answered is None else answered]:
        cell.source = answers[cell.metadata.nbgrader["grade_id"]]
    return nbformat.writes(student)


def _run_grade(argv: list[str]) -> int:
    return cli.main(["lessons", "grade", *argv])


# The lesson whose student notebook is graded untouched and partly done: the one that runs fastest.
STUB_AND_PARTIAL = REPO / "solutions" / "01_latency_zigzag.ipynb"


@pytest.mark.slow
def test_nbgrader_grades_solution_full_stub_zero_partial_between(tmp_path, capsys):
    submissions = tmp_path / "submitted"
    submitted = [("solution", path, None) for path in SOLUTIONS]
    assert len(_solution_cells(STUB_AND_PARTIAL)) >= 2, "a partial submission needs two exercises or more"
    # partial: only the first exercise done (the later ones fail fast instead of re-running the whole lesson)
    submitted += [("stub", STUB_AND_PARTIAL, 0), ("partial", STUB_AND_PARTIAL, 1)]
    for student, path, answered in submitted:
        (submissions / student).mkdir(parents=True, exist_ok=True)
        (submissions / student / path.name).write_text(_submission(path.name, answered))
    scores_csv = tmp_path / "scores.csv"
    assert _run_grade([str(submissions), "--csv", str(scores_csv), "--solutions", str(REPO / "solutions")]) == 0
    print(capsys.readouterr().out)
    with scores_csv.open() as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == SCORE_COLUMNS and len(rows) == len(submitted)
    table = {(row["student"], row["lesson"]): row for row in rows}
    for path in SOLUTIONS:
        full = table[("solution", path.stem)]
        assert float(full["max_score"]) >= 8
        assert float(full["score"]) == float(full["max_score"]) and full["failed_checks"] == "", full
    lesson = STUB_AND_PARTIAL.stem
    max_score = float(table[("solution", lesson)]["max_score"])
    zero, partial = table[("stub", lesson)], table[("partial", lesson)]
    assert float(zero["score"]) == 0.0 and float(zero["max_score"]) == max_score, zero
    checks = [cell.metadata.nbgrader["grade_id"] for cell in nbformat.read(STUB_AND_PARTIAL, as_version=4).cells
              if cell.metadata.nbgrader["grade"]]
    assert zero["failed_checks"].split(";") == checks, zero
    assert 0 < float(partial["score"]) < max_score, partial
    assert partial["failed_checks"], partial


def test_course_gradebook_is_stamped_with_the_revision_alembic_reports():
    """nbgrader stamps a new gradebook with what ``alembic heads`` prints for its migration scripts (a subprocess);
    the temporary course reads those scripts in-process and must come to the same revision."""
    import sqlite3

    from alembic.config import Config
    from alembic.script import ScriptDirectory
    from nbgrader.dbutil import _temp_alembic_ini

    with _temp_alembic_ini("sqlite:///unused.db") as alembic_ini:  # the configuration nbgrader hands to alembic
        heads = ScriptDirectory.from_config(Config(alembic_ini)).get_heads()
    with temporary_course({}) as root, contextlib.closing(sqlite3.connect(root / "gradebook.db")) as db:
        versions = [version for (version,) in db.execute("SELECT version_num FROM alembic_version")]
        courses = [course for (course,) in db.execute("SELECT id FROM course")]
    assert versions == heads and len(heads) == 1
    assert courses == ["plm_highway"]


def test_find_submissions_reads_student_folders_and_rejects_bad_input(tmp_path):
    (tmp_path / "ada").mkdir()
    (tmp_path / "ada" / "01_latency_zigzag.ipynb").write_text("{}")
    (tmp_path / "ada" / "notes.txt").write_text("ignored")
    assert find_submissions(tmp_path, ["01_latency_zigzag.ipynb"]) == {
        "ada": {"01_latency_zigzag.ipynb": tmp_path / "ada" / "01_latency_zigzag.ipynb"}}
    with pytest.raises(ValueError, match="no submissions"):
        find_submissions(tmp_path, ["02_teaching_a_car_to_look_ahead.ipynb"])
    with pytest.raises(ValueError, match="not a directory"):
        find_submissions(tmp_path / "missing", ["01_latency_zigzag.ipynb"])
    (tmp_path / "bad name;rm").mkdir()
    with pytest.raises(ValueError, match="student folder name"):
        find_submissions(tmp_path, ["01_latency_zigzag.ipynb"])


def test_scores_table_is_never_written_over_a_file_it_did_not_write(tmp_path):
    other = tmp_path / "grades.csv"
    other.write_text("name,grade\nada,A\n")
    for overwrite in (False, True):
        with pytest.raises(ValueError, match="not a lesson scores table that plm-highway wrote"):
            write_scores_csv([], other, overwrite=overwrite)
    assert other.read_text() == "name,grade\nada,A\n"
    ours = tmp_path / "scores.csv"
    write_scores_csv([], ours)
    with pytest.raises(ValueError, match="pass --overwrite"):
        write_scores_csv([], ours)
    write_scores_csv([], ours, overwrite=True)
    assert ours.read_text().splitlines() == [",".join(SCORE_COLUMNS)]
