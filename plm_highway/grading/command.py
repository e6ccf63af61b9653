"""``plm-highway lessons grade SUBMISSIONS_DIR --csv scores.csv``: autograde students' notebooks.

For an instructor without an nbgrader course: each ``SUBMISSIONS_DIR/<student>/<lesson>.ipynb`` is
autograded by nbgrader in a temporary course built from ``solutions/``; one row per student and lesson
(score, maximum, failed checks) goes to the CSV. Also ``plm-highway lessons figures``: the lessons'
target figures.
"""

from __future__ import annotations

from pathlib import Path

from plm_highway.grading.course import grade_submissions, write_scores_csv
from plm_highway.grading.notebooks import DEFAULT_FIGURES, DEFAULT_SOLUTIONS


def configure(parser) -> None:
    parser.add_argument("submissions", metavar="SUBMISSIONS_DIR", help="folder of <student>/<lesson>.ipynb")
    parser.add_argument("--csv", required=True, help="scores table to write (student, lesson, score, ...)")
    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks (nbgrader source)")
    parser.add_argument("--full", action="store_true", help="run the notebooks in full mode (PLM_FAST=0; slower, "
                        "the graded checks do not depend on it)")
    parser.add_argument("--overwrite", action="store_true", help="replace a scores table written before")


def run(args) -> int:
    scores = grade_submissions(Path(args.solutions), Path(args.submissions), fast=not args.full)
    write_scores_csv(scores, Path(args.csv), overwrite=args.overwrite)
    for score in scores:
        print(f"{score.student:>16} {score.lesson:<34} {score.score:g} / {score.max_score:g}")
    print(f"wrote {args.csv}")
    return 0


def configure_figures(parser) -> None:
    parser.add_argument("--out", default=DEFAULT_FIGURES, help="folder the PNGs are written to")
    parser.add_argument("--overwrite", action="store_true", help="replace lesson figures written before")


def run_figures(args) -> int:
    from plm_highway.grading.figures import write_lesson_figures

    for path in write_lesson_figures(Path(args.out), overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


def configure_timing(parser) -> None:
    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks")
    parser.add_argument("--fast", action="store_true", help="time the CI mode (PLM_FAST=1) instead of full mode")
    parser.add_argument("notebooks", nargs="*", help="only these notebooks (file names or stems)")


def run_timing(args) -> int:
    """``plm-highway bench lessons``: wall-clock time of each lesson, top to bottom, in a fresh kernel."""
    from plm_highway.grading.timing import time_lessons

    timings = time_lessons(Path(args.solutions), fast=args.fast, names=args.notebooks)
    for timing in timings:
        print(timing.line())
    return 1 if any(t.errors for t in timings) else 0
