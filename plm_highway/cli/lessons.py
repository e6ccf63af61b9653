"""``plm-highway lessons ...``: build the student notebooks from their single source, grade them, draw their figures."""

from __future__ import annotations

import sys

from plm_highway.cli._common import Command, add_overwrite, static_value

GROUP_HELP = "build, grade and illustrate the lessons (nbgrader)"


def configure_build(parser) -> None:
    # Read from the library's source, not imported: the help page imports no nbformat (tests/test_cli_help.py).
    DEFAULT_FIGURES, DEFAULT_LESSONS, DEFAULT_SOLUTIONS = (
        static_value("plm_highway.grading.notebooks", name)
        for name in ("DEFAULT_FIGURES", "DEFAULT_LESSONS", "DEFAULT_SOLUTIONS"))

    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks (nbgrader source)")
    parser.add_argument("--lessons", default=DEFAULT_LESSONS, help="folder the student notebooks are written to")
    parser.add_argument("--figures", default=DEFAULT_FIGURES, help="folder of the lessons' target figures (PNG)")
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if any notebook would change")


def run_build(args) -> int:
    from pathlib import Path

    from plm_highway.grading.notebooks import build

    changed = build(Path(args.solutions), Path(args.lessons), args.check, Path(args.figures))
    for path in changed:
        print(f"{'would change' if args.check else 'wrote'}: {path}")
    if args.check and changed:
        print("lessons are out of date: run 'plm-highway lessons build'", file=sys.stderr)
        return 1
    print("lessons up to date" if not changed else f"{len(changed)} notebook(s) written")
    return 0


def configure_grade(parser) -> None:
    # Read from the library's source, not imported: the help page imports no nbformat (tests/test_cli_help.py).
    DEFAULT_SOLUTIONS = static_value("plm_highway.grading.notebooks", "DEFAULT_SOLUTIONS")

    parser.add_argument("submissions", metavar="SUBMISSIONS_DIR", help="folder of <student>/<lesson>.ipynb")
    parser.add_argument("--csv", required=True, help="scores table to write (student, lesson, score, ...)")
    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks (nbgrader source)")
    parser.add_argument("--full", action="store_true", help="run the notebooks in full mode (PLM_FAST=0; slower, "
                        "the graded checks do not depend on it)")
    add_overwrite(parser)


def run_grade(args) -> int:
    from pathlib import Path

    from plm_highway.grading.course import SCORES_CSV, grade_submissions, write_scores_csv
    from plm_highway.io import check_target

    check_target(args.csv, SCORES_CSV, overwrite=args.overwrite)  # before minutes of autograding
    scores = grade_submissions(Path(args.solutions), Path(args.submissions), fast=not args.full)
    write_scores_csv(scores, Path(args.csv), overwrite=args.overwrite)
    for score in scores:
        print(f"{score.student:>16} {score.lesson:<34} {score.score:g} / {score.max_score:g}")
    print(f"wrote {args.csv}")
    return 0


def configure_figures(parser) -> None:
    # Read from the library's source, not imported: the help page imports no nbformat (tests/test_cli_help.py).
    DEFAULT_FIGURES = static_value("plm_highway.grading.notebooks", "DEFAULT_FIGURES")

    parser.add_argument("--out", default=DEFAULT_FIGURES, help="folder the PNGs are written to")
    add_overwrite(parser)


def run_figures(args) -> int:
    from pathlib import Path

    from plm_highway.grading.figures import write_lesson_figures

    for path in write_lesson_figures(Path(args.out), overwrite=args.overwrite):
        print(f"wrote {path}")
    return 0


def configure_timing(parser) -> None:
    # Read from the library's source, not imported: the help page imports no nbformat (tests/test_cli_help.py).
    DEFAULT_SOLUTIONS = static_value("plm_highway.grading.notebooks", "DEFAULT_SOLUTIONS")

    parser.add_argument("--solutions", default=DEFAULT_SOLUTIONS, help="folder of solution notebooks")
    parser.add_argument("--fast", action="store_true", help="time the CI mode (PLM_FAST=1) instead of full mode")
    parser.add_argument("notebooks", nargs="*", help="only these notebooks (file names or stems)")


def run_timing(args) -> int:
    """Wall-clock time of each lesson, top to bottom, in a fresh kernel."""
    from pathlib import Path

    from plm_highway.grading.timing import time_lessons

    timings = time_lessons(Path(args.solutions), fast=args.fast, names=args.notebooks)
    for timing in timings:
        print(timing.line())
    return 1 if any(t.errors for t in timings) else 0


COMMANDS = [
    Command("build", "generate lessons/ from solutions/ with nbgrader (or --check)", configure_build, run_build),
    Command("grade", "autograde students' notebooks into a scores table", configure_grade, run_grade),
    Command("figures", "draw the lessons' target figures", configure_figures, run_figures),
]
