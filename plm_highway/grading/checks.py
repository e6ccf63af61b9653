"""What every graded check shares: run the student's code, compare, explain in one short block.

A check raises :class:`CheckFailed` with what was checked, what was expected, what came back and a
hint. In a notebook the failure renders as that block alone (IPython's ``_render_traceback_``): the
grading code's frames are not shown, because they say nothing a student can act on. Where the
student's own code raised, the block names the line of *their* code that did.

A student function that still raises ``NotImplementedError`` fails with "not implemented yet"; one
that hands the work to the kit's own implementation of the exercise fails with "you called
plm_highway's own ...: write it yourself" (see :mod:`plm_highway.grading.delegation`).
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import traceback
from pathlib import Path

import numpy as np

from plm_highway.grading.delegation import DelegationDetected, blocked_references

_GRADING_DIR = str(Path(__file__).resolve().parent)
_current_check: contextvars.ContextVar[str | None] = contextvars.ContextVar("current_check", default=None)
MAX_BLOCK_LINES = 12  # a failure block never grows beyond this many lines (tests assert it)


class CheckFailed(AssertionError):
    """A graded check failed. ``str()`` and the notebook rendering carry the same short block."""

    def __init__(self, checked: str, expected=None, received=None, hint: str = "", details: list[str] | None = None,
                 *, headline: str | None = None):
        self.check = _current_check.get()
        self.checked = checked
        self.headline = headline
        self.lines = _block_lines(checked, expected, received, hint, details or [], headline)
        super().__init__("\n".join(self.lines))

    def _render_traceback_(self) -> list[str]:  # IPython shows exactly these lines instead of a traceback
        title = f"FAILED {self.check}" if self.check else "FAILED"
        return [f"\x1b[1;31m{title}\x1b[0m", *("  " + line for line in self.lines)]


def _block_lines(checked, expected, received, hint, details, headline) -> list[str]:
    lines = [headline] if headline else []
    lines.append(f"checked:  {checked}")
    if expected is not None or received is not None:
        lines.append(f"expected: {expected}")
        lines.append(f"received: {received}")
    lines.extend(details)
    if hint:
        lines.append(f"hint:     {hint}")
    if len(lines) > MAX_BLOCK_LINES:
        lines = lines[: MAX_BLOCK_LINES - 1] + ["..."]
    return [_shorten(line) for line in lines]


def _shorten(line: str, limit: int = 300) -> str:
    return line if len(line) <= limit else line[: limit - 3] + "..."


# --- Numbers that print cleanly -------------------------------------------------------------------------


def format_number(value, other=None) -> str:
    """A float without artefacts ("2", "0.175", "1.2e-07"); with ``other`` given, enough digits to
    tell the two apart, so that "expected" and "received" never look identical when they differ."""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    if not np.isfinite(value):
        return str(value)
    for digits in (6, 9, 12, 17):
        text = _float_text(value, digits)
        if other is None or not np.isfinite(float(other)) or float(other) == value:
            return text
        if text != _float_text(float(other), digits):
            return text
    return repr(value)


def _float_text(value: float, digits: int) -> str:
    if value != 0 and (abs(value) < 1e-4 or abs(value) >= 1e7):
        return np.format_float_scientific(value, precision=digits - 1, unique=True, trim="-", exp_digits=1)
    text = np.format_float_positional(value, precision=digits, unique=True, fractional=False, trim="-")
    return text


def format_value(value, other=None) -> str:
    """Numbers and small arrays printed cleanly (digits enough to differ from ``other``); anything else by repr."""
    if isinstance(value, (int, float, np.integer, np.floating, bool, np.bool_)):
        return format_number(value, other if _is_number(other) else None)
    if isinstance(value, (str, bytes)) or value is None:
        return repr(value)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return _shorten(repr(value), 120)
    if array.ndim == 0:
        return format_number(float(array))
    if array.size > 8:
        return f"array of shape {array.shape}"
    try:
        others = np.broadcast_to(np.asarray(other, dtype=float), array.shape) if other is not None else None
    except (TypeError, ValueError):
        others = None
    flat = [format_number(v, None if others is None else o)
            for v, o in zip(array.ravel(), others.ravel() if others is not None else [None] * array.size)]
    text = ", ".join(flat)
    if array.ndim == 1:
        return f"[{text}]"
    return f"array of shape {array.shape}: [{text}]"


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def array_difference(expected: np.ndarray, received: np.ndarray, atol: float, rtol: float) -> list[str]:
    """Where two equal-shape arrays differ: first index, the values there, the largest difference."""
    wrong = ~np.isclose(received, expected, atol=atol, rtol=rtol)
    indices = np.argwhere(wrong)
    first = tuple(int(i) for i in indices[0])
    gap = np.abs(received - expected)
    gap = np.where(np.isnan(gap), np.inf, gap)
    largest = tuple(int(i) for i in np.unravel_index(int(np.argmax(gap)), gap.shape))
    index = first[0] if len(first) == 1 else first
    worst = largest[0] if len(largest) == 1 else largest
    tolerance = format_number(atol) if rtol == 0 else f"{format_number(atol)} + {format_number(rtol)} x |expected|"
    return [f"first difference at index {index}: expected {format_number(expected[first], received[first])}, "
            f"received {format_number(received[first], expected[first])}",
            f"largest difference {format_number(float(gap[largest]))} at index {worst}; "
            f"{int(wrong.sum())} of {wrong.size} values differ (tolerance {tolerance})"]


# --- Comparisons ---------------------------------------------------------------------------------------------


def expect_close(what: str, expected, received, atol: float = 1e-9, rtol: float = 0.0, hint: str = "") -> None:
    """Numbers or arrays equal within ``atol + rtol * |expected|``."""
    expected_arr = np.asarray(expected, dtype=float)
    try:
        received_arr = np.asarray(received, dtype=float)
    except (TypeError, ValueError):
        raise CheckFailed(what, format_value(expected), f"{type(received).__name__} {_shorten(repr(received), 80)}",
                          "return a number or an array of numbers") from None
    if expected_arr.shape != received_arr.shape:
        raise CheckFailed(what, f"shape {expected_arr.shape}", f"shape {received_arr.shape}",
                          hint or "return an array of the expected shape")
    if np.all(np.isclose(received_arr, expected_arr, atol=atol, rtol=rtol)):
        return
    if expected_arr.size == 1:
        raise CheckFailed(what, format_value(float(expected_arr.ravel()[0]), float(received_arr.ravel()[0])),
                          format_value(float(received_arr.ravel()[0]), float(expected_arr.ravel()[0])), hint)
    details = array_difference(expected_arr, received_arr, atol, rtol)
    if expected_arr.size <= 8:
        raise CheckFailed(what, format_value(expected_arr, received_arr), format_value(received_arr, expected_arr),
                          hint, details[1:])
    raise CheckFailed(what, f"array of shape {expected_arr.shape}", f"array of shape {received_arr.shape}", hint,
                      details)


def expect_equal(what: str, expected, received, hint: str = "") -> None:
    if not (expected == received):
        raise CheckFailed(what, format_value(expected, received), format_value(received, expected), hint)


def expect_true(condition: bool, what: str, hint: str = "", expected=None, received=None) -> None:
    if not condition:
        raise CheckFailed(what, expected, received, hint)


# --- Calling student code --------------------------------------------------------------------------------


def call_student(function, *args, what: str, exercise: str | None = None, **kwargs):
    """Call the student's ``function`` with the kit's implementations of ``exercise`` unavailable.

    Turns "not implemented", delegation to the kit and any exception of the student's code into a
    :class:`CheckFailed` that shows where in *their* code it happened.
    """
    try:
        with blocked_references(exercise, function) as tripped:
            result = function(*args, **kwargs)
    except CheckFailed:
        raise
    except NotImplementedError:
        raise CheckFailed(what, headline="not implemented yet",
                          hint="replace the `raise NotImplementedError()` line with your code") from None
    except DelegationDetected as error:
        raise _delegation_failure(what, error.reference) from None
    except Exception as error:  # any error of the student's code becomes readable feedback
        raise CheckFailed(what, headline=f"your code raised {type(error).__name__}: {_shorten(str(error), 160)}",
                          details=_student_frames(error), hint="read the line above; run your function by hand "
                          "on a small input") from None
    if tripped:
        raise _delegation_failure(what, tripped[0])
    return result


def _delegation_failure(what: str, reference) -> CheckFailed:
    whose = "plm_highway's own" if reference.name.startswith("plm_highway") else "a library's"
    name = reference.name.replace(":", ".")
    return CheckFailed(what, headline=f"you called {whose} {reference.what} ({name}): write it yourself",
                       hint="this exercise asks for your implementation; the kit's is switched off while the "
                       "check runs")


def _student_frames(error: BaseException, limit: int = 2) -> list[str]:
    """The last frames of the traceback that are not the grading code's or a library's."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if not f.filename.startswith(_GRADING_DIR)
              and "site-packages" not in f.filename and "/lib/python" not in f.filename]
    return [f"in {frame.name}, line {frame.lineno}" + (f": {frame.line.strip()}" if frame.line else "")
            for frame in frames[-limit:]]


# --- The decorator every check wears ----------------------------------------------------------------------


def graded(points: int):
    """Mark a check with its points (nbgrader's grade cell carries the same number), print one
    verdict line when it passes, and turn a crash inside the check (on a malformed return value)
    into a readable failure."""
    def decorate(check):
        @functools.wraps(check)
        def wrapper(*args, **kwargs):
            token = _current_check.set(check.__name__)
            try:
                result = check(*args, **kwargs)
            except CheckFailed:
                raise
            except Exception as error:  # the check could not use what the student's code returned
                raise CheckFailed(f"what your code returned, in {check.__name__}",
                                  headline=f"the check could not use it: {type(error).__name__}: "
                                           f"{_shorten(str(error), 160)}",
                                  hint="return the types and shapes the exercise text asks for") from None
            finally:
                _current_check.reset(token)
            hidden = kwargs.get("seed") is not None
            print(f"PASSED {check.__name__}" + (" (further cases)" if hidden else
                                                 f" ({points} point{'s' if points != 1 else ''})"))
            return result
        wrapper.points = points
        return wrapper
    return decorate


@contextlib.contextmanager
def current_check(name: str):
    """Name the check for failures raised outside a ``graded`` function (used by tests)."""
    token = _current_check.set(name)
    try:
        yield
    finally:
        _current_check.reset(token)
