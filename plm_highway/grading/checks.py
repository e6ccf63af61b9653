"""What every graded check shares: run the student's code, compare, explain.

A check raises ``AssertionError`` with what was expected, what came back and a hint; a student
function that still raises ``NotImplementedError`` fails with "not implemented yet". A check
that passes prints one line with its points.
"""

from __future__ import annotations

import functools

import numpy as np


class CheckFailed(AssertionError):
    """A graded check failed; the message says what was expected, what came back and a hint."""


def call_student(function, *args, what: str, **kwargs):
    """Call the student's ``function``; turn 'not implemented' into a clear failed check."""
    try:
        return function(*args, **kwargs)
    except NotImplementedError:
        raise CheckFailed(f"not implemented yet: {what}. Replace the `raise NotImplementedError` line.") from None


def expect_close(what: str, expected, received, atol: float = 1e-9, rtol: float = 0.0, hint: str = "") -> None:
    expected_arr = np.asarray(expected, dtype=float)
    try:
        received_arr = np.asarray(received, dtype=float)
    except (TypeError, ValueError):
        raise CheckFailed(f"{what}: expected a number or array like {expected!r}, received {received!r}. {hint}") from None
    if expected_arr.shape != received_arr.shape or not np.allclose(received_arr, expected_arr, atol=atol, rtol=rtol):
        raise CheckFailed(f"{what}: expected {_short(expected)}, received {_short(received)}. Hint: {hint}")


def expect_true(condition: bool, message: str, hint: str = "") -> None:
    if not condition:
        raise CheckFailed(f"{message}. Hint: {hint}")


def graded(points: int):
    """Mark a check function with its points and print a one-line verdict when it passes."""
    def decorate(check):
        @functools.wraps(check)
        def wrapper(*args, **kwargs):
            result = check(*args, **kwargs)
            print(f"PASSED {check.__name__} ({points} point{'s' if points != 1 else ''})")
            return result
        wrapper.points = points
        return wrapper
    return decorate


def _short(value) -> str:
    array = np.asarray(value) if not isinstance(value, str) else None
    if array is not None and array.size > 8:
        return f"array of shape {array.shape} starting {np.array2string(array.ravel()[:6], precision=4)}"
    return repr(value) if array is None else np.array2string(array, precision=6)
