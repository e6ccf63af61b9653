"""nbgrader grades every lesson end to end: the worked solution gets full marks, the untouched student
notebook zero, a partly done one the points in between. Runs the instructor's command
(``plm-highway lessons grade``), which autogrades with nbgrader in a temporary course."""

from __future__ import annotations

import csv
from pathlib import Path

import nbformat
import pytest

from plm_highway import cli
from plm_highway.grading.course import SCORE_COLUMNS, find_submissions, write_scores_csv

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


@pytest.mark.slow
def test_nbgrader_grades_solution_full_stub_zero_partial_between(tmp_path, capsys):
    submissions = tmp_path / "submitted"
    for path in SOLUTIONS:
        assert len(_solution_cells(path)) >= 2, f"{path.name}: a partial submission needs two exercises or more"
        # partial: only the first exercise done (the later ones fail fast instead of re-running the whole lesson)
        for student, answered in (("solution", None), ("stub", 0), ("partial", 1)):
            (submissions / student).mkdir(parents=True, exist_ok=True)
            (submissions / student / path.name).write_text(_submission(path.name, answered))
    scores_csv = tmp_path / "scores.csv"
    assert _run_grade([str(submissions), "--csv", str(scores_csv), "--solutions", str(REPO / "solutions")]) == 0
    print(capsys.readouterr().out)
    with scores_csv.open() as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == SCORE_COLUMNS and len(rows) == 3 * len(SOLUTIONS)
    table = {(row["student"], row["lesson"]): row for row in rows}
    for path in SOLUTIONS:
        lesson = path.stem
        full, zero, partial = (table[(student, lesson)] for student in ("solution", "stub", "partial"))
        max_score = float(full["max_score"])
        assert max_score >= 8
        assert float(full["score"]) == max_score and full["failed_checks"] == "", full
        assert float(zero["score"]) == 0.0, zero
        assert 0 < float(partial["score"]) < max_score, partial
        assert partial["failed_checks"], partial


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
