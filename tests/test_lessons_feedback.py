"""Feedback a student can read, and checks that cannot be passed by calling the kit."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from nbclient import NotebookClient
from nbformat import v4

from plm_highway.grading import lesson2, lesson3, lesson4
from plm_highway.grading.checks import (
    MAX_BLOCK_LINES,
    CheckFailed,
    call_student,
    current_check,
    expect_close,
    format_number,
    format_value,
)
from plm_highway.grading.delegation import REFERENCES, blocked_references, resolve

ANSI = re.compile(r"\x1b\[[0-9;]*m")


# --- numbers --------------------------------------------------------------------------------------------------


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_format_number_reads_back_and_has_no_artefacts(value):
    text = format_number(value)
    assert ".." not in text and not text.endswith(".") and " " not in text
    assert math.isclose(float(text), value, rel_tol=1e-5, abs_tol=0.0) or value == float(text)


@given(st.floats(-1e6, 1e6, allow_nan=False), st.floats(-1e6, 1e6, allow_nan=False))
def test_different_numbers_never_print_alike(a, b):
    if a != b:
        assert format_number(a, b) != format_number(b, a)


@pytest.mark.parametrize(("value", "text"), [(2.0, "2"), (0.175, "0.175"), (-100.0, "-100"), (1.2e-7, "1.2e-7"),
                                             (np.float32(0.25), "0.25"), (3, "3"), (True, "True")])
def test_format_number_examples(value, text):
    assert format_number(value) == text


def test_small_arrays_print_every_value_cleanly():
    assert format_value([2.0, 0.5, -1.0]) == "[2, 0.5, -1]"
    assert format_value(np.arange(20.0)) == "array of shape (20,)"


# --- the failure block ---------------------------------------------------------------------------------------


def test_array_failure_names_first_difference_values_and_largest_gap():
    expected = np.linspace(0.0, 1.0, 50)
    received = expected.copy()
    received[17] += 1e-7
    received[42] += 0.25
    with pytest.raises(CheckFailed) as info, current_check("check_demo"):
        expect_close("demo series", expected, received, atol=1e-9, hint="look at index 17")
    block = [ANSI.sub("", line) for line in info.value._render_traceback_()]
    assert block[0] == "FAILED check_demo"
    text = "\n".join(block)
    assert "first difference at index 17: expected 0.346938776, received 0.346938876" in text
    assert "largest difference 0.25 at index 42; 2 of 50 values differ (tolerance 1e-9)" in text
    assert "hint:     look at index 17" in text
    assert len(block) <= MAX_BLOCK_LINES + 1


def test_a_crash_in_student_code_shows_their_line_not_the_graders():
    def student(xy, spacing_m):
        return xy[10]

    with pytest.raises(CheckFailed) as info:
        lesson3.check_resample(student)
    text = str(info.value)
    assert "your code raised IndexError" in text and "return xy[10]" in text
    assert "plm_highway/grading" not in text and len(text.splitlines()) <= MAX_BLOCK_LINES


def test_failed_check_renders_as_one_short_block_in_a_kernel():
    notebook = v4.new_notebook(cells=[v4.new_code_cell(
        "import numpy as np\nfrom plm_highway.grading import lesson4\n"
        "def replay_yaw_rate(steer, speed, lf, lr):\n    return speed * np.tan(steer) / (lf + lr)\n"
        "lesson4.check_replay(replay_yaw_rate)")])
    NotebookClient(notebook, timeout=300, allow_errors=True, kernel_name="python3").execute()
    (error,) = [out for out in notebook.cells[0].outputs if out.output_type == "error"]
    block = [ANSI.sub("", line) for line in error.traceback]
    assert error.ename == "CheckFailed"
    assert block[0] == "FAILED check_replay" and len(block) <= MAX_BLOCK_LINES + 1, block
    text = "\n".join(block)
    assert "checked:  replay_yaw_rate with lf=2.5, lr=2.5" in text and "first difference at index" in text
    assert "hint:" in text and "File " not in text and "Traceback" not in text


# --- delegation ------------------------------------------------------------------------------------------------


def test_every_blocked_reference_resolves():
    """A rename elsewhere makes this fail: update the entry in plm_highway/grading/delegation.py."""
    for reference in REFERENCES:
        resolve(reference.name)


@pytest.mark.parametrize("reference", REFERENCES, ids=lambda r: f"{r.exercise}-{r.name}")
def test_each_reference_trips_while_blocked_and_works_after(reference):
    target = resolve(reference.name)
    with blocked_references(reference.exercise) as tripped:
        with pytest.raises(Exception, match="switched off"):
            resolve(reference.name)()  # a rebound object is replaced where it is bound, not in place
        assert tripped and tripped[-1].name in {r.name for r in REFERENCES if r.exercise == reference.exercise}
    assert resolve(reference.name) is target
    if not isinstance(target, type):
        with pytest.raises(Exception) as info:  # the real function is back: it complains about missing arguments
            target()
        assert "switched off" not in str(info.value)


def test_delegation_is_caught_even_when_imported_first_and_the_error_swallowed():
    from plm_highway.models.plm_net import interpolate_actions as kit  # imported before the check

    def interpolate(latency_s, delta_ref_s, a_ref):
        try:
            return kit(latency_s, delta_ref_s, a_ref)
        except Exception:
            return np.zeros(len(latency_s))

    with pytest.raises(CheckFailed, match=r"you called plm_highway's own Algorithm 1 .*write it yourself"):
        lesson2.check_interpolate_by_hand(interpolate)
    assert kit(np.array([0.1]), np.array([0.0, 0.2]), np.array([[0.0, 1.0]])) == pytest.approx([0.5])


def test_the_checker_still_uses_the_references_it_blocks_for_students():
    def replay_yaw_rate(steer, speed, lf, lr):
        beta = np.arctan(lr / (lf + lr) * np.tan(steer))
        return speed * np.sin(beta) / lr

    lesson4.check_replay(replay_yaw_rate)
    lesson4.check_replay(replay_yaw_rate, seed=3)


def test_call_student_without_exercise_blocks_nothing():
    from plm_highway.metrics import frechet_dist

    assert call_student(frechet_dist, np.zeros((2, 2)), np.ones((2, 2)), what="x") == pytest.approx(math.sqrt(2))
