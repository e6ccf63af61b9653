"""Type and range checks for architecture configs, which arrive from checkpoint JSON.

A config is checked in full before any layer is allocated: a wrong type or an out-of-range size
is a ValueError naming the field, the value and the accepted range, never a TypeError deep in
torch or a multi-gigabyte allocation.
"""

from __future__ import annotations

import math


def check_int(field: str, value, low: int, high: int) -> int:
    """An integer (not a bool, not a float such as 66.0) in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{field}: expected an integer in [{low}, {high}], got {type(value).__name__} {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{field}: must lie in [{low}, {high}], got {value}")
    return value


def check_number(field: str, value, low: float, high: float, *, low_open: bool = False, high_open: bool = False
                 ) -> float:
    """A finite real number (int or float, not a bool) in the interval from ``low`` to ``high``."""
    interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{field}: expected a number in {interval}, got {type(value).__name__} {value!r}")
    value = float(value)
    inside = (
        math.isfinite(value)
        and (value > low if low_open else value >= low)
        and (value < high if high_open else value <= high)
    )
    if not inside:
        raise ValueError(f"{field}: must be a finite number in {interval}, got {value}")
    return value


def check_bool(field: str, value) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{field}: expected true or false, got {type(value).__name__} {value!r}")
    return value


def check_choice(field: str, value, choices: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{field}: {value!r} is not one of {list(choices)}")
    return value
