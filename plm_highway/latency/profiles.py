"""Latency profiles: how late the camera is, as a function of time since reset.

Spec strings (``parse_profile``):

- ``const:0.2`` - always 0.2 s (``none`` is ``const:0``).
- ``steps:0.0-0.35:1.0`` - a value drawn uniformly from [0.0, 0.35] s, redrawn every 1.0 s
  (the original PLM-Net experiment redrew about every second). Seeded at each reset.
- ``sine:MEAN:AMP:PERIOD`` - MEAN + AMP sin(2 pi t / PERIOD); it must stay non-negative.
- ``ramp:FROM-TO:SECONDS`` - linear from FROM to TO over SECONDS, then held at TO.
- ``trace:PATH.csv`` - a CSV with columns ``t`` and ``latency_s``, interpolated linearly in
  time and held at its first and last values outside its range.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class LatencyProfile:
    """Latency [s] as a function of time since reset [s]."""

    spec: str

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new realisation (only random profiles use ``rng``)."""

    def latency_s(self, t_s: float) -> float:
        raise NotImplementedError

    @property
    def max_latency_s(self) -> float:
        raise NotImplementedError

    def __str__(self) -> str:
        return self.spec


@dataclass
class ConstantProfile(LatencyProfile):
    value_s: float
    spec: str = ""

    def latency_s(self, t_s: float) -> float:
        return self.value_s

    @property
    def max_latency_s(self) -> float:
        return self.value_s


@dataclass
class StepsProfile(LatencyProfile):
    low_s: float
    high_s: float
    period_s: float
    spec: str = ""
    _values_s: list[float] = field(default_factory=list, repr=False)
    _rng: np.random.Generator | None = field(default=None, repr=False)

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._values_s = []

    def latency_s(self, t_s: float) -> float:
        if self._rng is None:
            raise RuntimeError(f"{self.spec}: reset(rng) must be called before use")
        index = int(math.floor(max(t_s, 0.0) / self.period_s + 1e-9))
        # Draw lazily but in order, so the realisation depends only on the seed.
        while len(self._values_s) <= index:
            self._values_s.append(float(self._rng.uniform(self.low_s, self.high_s)))
        return self._values_s[index]

    @property
    def max_latency_s(self) -> float:
        return self.high_s


@dataclass
class SineProfile(LatencyProfile):
    mean_s: float
    amplitude_s: float
    period_s: float
    spec: str = ""

    def latency_s(self, t_s: float) -> float:
        return self.mean_s + self.amplitude_s * math.sin(2 * math.pi * t_s / self.period_s)

    @property
    def max_latency_s(self) -> float:
        return self.mean_s + abs(self.amplitude_s)


@dataclass
class RampProfile(LatencyProfile):
    from_s: float
    to_s: float
    duration_s: float
    spec: str = ""

    def latency_s(self, t_s: float) -> float:
        fraction = min(max(t_s / self.duration_s, 0.0), 1.0)
        return self.from_s + (self.to_s - self.from_s) * fraction

    @property
    def max_latency_s(self) -> float:
        return max(self.from_s, self.to_s)


@dataclass
class TraceProfile(LatencyProfile):
    t_s: np.ndarray
    values_s: np.ndarray
    spec: str = ""

    def latency_s(self, t_s: float) -> float:
        return float(np.interp(t_s, self.t_s, self.values_s))

    @property
    def max_latency_s(self) -> float:
        return float(self.values_s.max())


def parse_profile(spec: str | LatencyProfile | float) -> LatencyProfile:
    """Parse a latency spec; a ValueError quotes the offending text."""
    if isinstance(spec, LatencyProfile):
        return spec
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        spec = f"const:{spec}"
    if not isinstance(spec, str):
        raise ValueError(f"latency spec {spec!r}: expected a string such as 'const:0.2'")
    text = spec.strip()
    if text in ("none", "0", ""):
        text = "const:0"
    kind, _, rest = text.partition(":")
    parsers = {"const": _parse_const, "steps": _parse_steps, "sine": _parse_sine, "ramp": _parse_ramp,
               "trace": _parse_trace}
    if kind not in parsers or not rest:
        raise ValueError(
            f"latency spec {spec!r}: expected one of const:S, steps:LO-HI:PERIOD, sine:MEAN:AMP:PERIOD, "
            f"ramp:FROM-TO:SECONDS, trace:PATH.csv"
        )
    profile = parsers[kind](rest, spec)
    profile.spec = text
    return profile


def _number(text: str, spec: str, what: str, positive: bool = False) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"latency spec {spec!r}: {what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"latency spec {spec!r}: {what} {text!r} is not finite")
    if value < 0 or (positive and value == 0):
        raise ValueError(f"latency spec {spec!r}: {what} {text!r} must be {'positive' if positive else '>= 0'}")
    return value


def _range(text: str, spec: str, what: str) -> tuple[float, float]:
    # Split at the first '-' that is not a sign (leading, or an exponent's as in 1e-05).
    split = next((i for i, char in enumerate(text) if char == "-" and i > 0 and text[i - 1] not in "eE"), None)
    if split is None:
        raise ValueError(f"latency spec {spec!r}: {what} {text!r} must look like LO-HI")
    low, high = text[:split], text[split + 1:]
    return _number(low, spec, f"{what} start"), _number(high, spec, f"{what} end")


def _fields(rest: str, spec: str, count: int) -> list[str]:
    parts = rest.split(":")
    if len(parts) != count:
        raise ValueError(f"latency spec {spec!r}: expected {count} ':'-separated fields after the kind, got {len(parts)}")
    return parts


def _parse_const(rest: str, spec: str) -> LatencyProfile:
    (value,) = _fields(rest, spec, 1)
    return ConstantProfile(_number(value, spec, "latency"))


def _parse_steps(rest: str, spec: str) -> LatencyProfile:
    span, period = _fields(rest, spec, 2)
    low_s, high_s = _range(span, spec, "range")
    if high_s < low_s:
        raise ValueError(f"latency spec {spec!r}: range {span!r} ends below its start")
    return StepsProfile(low_s, high_s, _number(period, spec, "period", positive=True))


def _parse_sine(rest: str, spec: str) -> LatencyProfile:
    mean, amplitude, period = _fields(rest, spec, 3)
    mean_s, amplitude_s = _number(mean, spec, "mean"), _number(amplitude, spec, "amplitude")
    if amplitude_s > mean_s:
        raise ValueError(f"latency spec {spec!r}: amplitude {amplitude!r} exceeds mean {mean!r}; latency would be negative")
    return SineProfile(mean_s, amplitude_s, _number(period, spec, "period", positive=True))


def _parse_ramp(rest: str, spec: str) -> LatencyProfile:
    span, duration = _fields(rest, spec, 2)
    from_s, to_s = _range(span, spec, "range")
    return RampProfile(from_s, to_s, _number(duration, spec, "duration", positive=True))


def _parse_trace(rest: str, spec: str) -> LatencyProfile:
    path = Path(rest)
    if not path.is_file():
        raise ValueError(f"latency spec {spec!r}: trace file {str(path)!r} does not exist")
    t_s, values_s = read_trace(path)
    return TraceProfile(t_s, values_s)


def read_trace(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a latency trace CSV (columns ``t``, ``latency_s``); errors name the file and row."""
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        missing = {"t", "latency_s"} - set(reader.fieldnames or [])
        if missing:
            raise ValueError(f"{path}: missing columns {sorted(missing)} (header: {reader.fieldnames})")
        times, values = [], []
        for row_number, row in enumerate(reader, start=2):
            for name in ("t", "latency_s"):
                try:
                    value = float(row[name])
                except (TypeError, ValueError):
                    raise ValueError(f"{path}: row {row_number}, column {name!r}: {row[name]!r} is not a number") from None
                if not math.isfinite(value):
                    raise ValueError(f"{path}: row {row_number}, column {name!r}: {row[name]!r} is not finite")
            t, latency = float(row["t"]), float(row["latency_s"])
            if latency < 0:
                raise ValueError(f"{path}: row {row_number}, column 'latency_s': {latency} is negative")
            if times and t <= times[-1]:
                raise ValueError(f"{path}: row {row_number}, column 't': {t} does not increase")
            times.append(t)
            values.append(latency)
    if not times:
        raise ValueError(f"{path}: no rows")
    return np.array(times), np.array(values)
