"""The mutation battery: every graded check catches at least 90% of the wrong implementations aimed at it.

The mutants are data (``tests/lesson_mutants.py``); each is run through the checks it is aimed at exactly
as nbgrader's autograder runs a grade cell (hidden tests included). The worked solution passes every
check (the control), so a caught mutant is caught for what it changed.
"""

from __future__ import annotations

import collections
import contextlib
import io

import pytest
from lesson_harness import exercise_namespace, run_check, solution_path
from lesson_mutants import MUTANTS, Mutant

from plm_highway.grading.checks import CheckFailed
from plm_highway.grading.course import check_calls

CATCH_RATE = 0.9
LESSONS = sorted({mutant.lesson for mutant in MUTANTS})
SLOW_CHECKS = {"check_zigzag", "check_table_3", "check_trap_table"}


@pytest.fixture(scope="module")
def extras():
    """What the grade cells need beside the exercises: the lesson's data and fast-mode settings."""
    from plm_highway.data.collect import collect

    _, steps, _ = collect(track="train", episodes=2, episode_seconds=3.0, seed=0, progress=False)
    return {"01": {}, "02": {"steps": steps}, "03": {"MAX_STEPS": 60, "CHECKPOINTS": None}, "04": {},
            "05": {}}


def _grade_cell_checks(lesson: str) -> list[str]:
    import nbformat

    cells = nbformat.read(solution_path(lesson), as_version=4).cells
    return [check_calls(cell.source)[0][1] for cell in cells if cell.cell_type == "code" and check_calls(cell.source)]


def _outcome(mutant: Mutant, check: str, extras: dict) -> CheckFailed | None:
    namespace = exercise_namespace(mutant.lesson, mutant.old, mutant.new, extras.get(mutant.lesson))
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            run_check(mutant.lesson, check, namespace)
        except CheckFailed as failure:
            return failure
    return None


def _catch_table(mutants: list[Mutant], extras: dict) -> dict[str, list[tuple[Mutant, CheckFailed | None]]]:
    table: dict[str, list] = collections.defaultdict(list)
    for mutant in mutants:
        for check in mutant.checks:
            table[check].append((mutant, _outcome(mutant, check, extras)))
    return table


def _assert_rates(table) -> None:
    lines, failing = [], []
    for check, outcomes in sorted(table.items()):
        caught = sum(failure is not None for _, failure in outcomes)
        rate = caught / len(outcomes)
        lines.append(f"{check}: {caught}/{len(outcomes)} = {rate:.0%}")
        if rate < CATCH_RATE:
            failing.append(check)
        for mutant, failure in outcomes:
            if failure is None:
                lines.append(f"    survived: {mutant.why}")
            elif mutant.delegation:
                assert "write it yourself" in str(failure), f"{mutant.why}: failed without naming the delegation:\n" \
                                                             f"{failure}"
    print("\n".join(lines))
    assert not failing, "checks below the catch rate:\n" + "\n".join(lines)


def test_battery_is_large_enough_and_aims_at_real_checks():
    assert len(MUTANTS) >= 40
    for lesson in LESSONS:
        checks = set(_grade_cell_checks(lesson))
        aimed = {check for mutant in MUTANTS if mutant.lesson == lesson for check in mutant.checks}
        assert aimed <= checks, f"lesson {lesson}: mutants aimed at checks the notebook does not call: {aimed - checks}"
        assert checks <= aimed, f"lesson {lesson}: checks without a mutant: {checks - aimed}"


@pytest.mark.parametrize("lesson", LESSONS)
def test_worked_solution_passes_every_check(lesson, extras):
    namespace = exercise_namespace(lesson, extra=extras[lesson])
    for check in _grade_cell_checks(lesson):
        if check in SLOW_CHECKS:
            continue  # driven in test_closed_loop_checks_catch_their_mutants
        output = io.StringIO()
        with contextlib.redirect_stdout(output):
            run_check(lesson, check, namespace)
        assert f"PASSED {check}" in output.getvalue()


@pytest.mark.parametrize("lesson", LESSONS)
def test_each_check_catches_its_mutants(lesson, extras):
    _assert_rates(_catch_table([m for m in MUTANTS if m.lesson == lesson and not m.slow], extras))


@pytest.mark.slow
def test_closed_loop_checks_catch_their_mutants(extras):
    for lesson, check in (("01", "check_zigzag"), ("03", "check_table_3"), ("03", "check_trap_table")):
        namespace = exercise_namespace(lesson, extra=extras[lesson])
        with contextlib.redirect_stdout(io.StringIO()):
            run_check(lesson, check, namespace)  # the control passes
    _assert_rates(_catch_table([m for m in MUTANTS if m.slow], extras))
