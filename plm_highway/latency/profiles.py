"""Latency profiles: how late the camera is, as a function of time since reset.

Spec strings (``parse_profile``); ``S``, ``LO``, ``HI`` ... are plain decimal numbers such as ``0.2``
or ``1e-3`` (no sign, ``nan``, ``inf``, hex or ``_``):

- ``none``, ``S`` or ``const:S`` - always S seconds (``none`` and ``0`` mean no latency).
- ``steps:LO-HI:PERIOD`` - a value drawn uniformly from [LO, HI] s, redrawn every PERIOD s.
  ``steps:0.0-0.35:1.0`` is the time-varying profile as the PLM-Net paper states it.
- ``frames:LO-HI:EVERY@RATE`` - an integer number of frames drawn uniformly from LO..HI (both
  included), redrawn every EVERY frames, of a loop running at RATE Hz; the latency is
  frames / RATE seconds. ``frames:9-21:60@30`` is what the original PLM-Net code did (its ROS loop
  ran at 30 Hz: 0.30..0.70 s redrawn every 2 s); ``frames:9-21:60@60`` is how the paper reads the
  same numbers (60 fps: 0.15..0.35 s redrawn every 1 s). Both readings are runnable because the
  original's timebase is ambiguous.
- ``sine:MEAN:AMP:PERIOD`` - MEAN + AMP sin(2 pi t / PERIOD); AMP <= MEAN so it stays >= 0.
- ``ramp:FROM-TO:SECONDS`` - linear from FROM to TO over SECONDS, then held at TO.
- ``trace:PATH.csv`` - a CSV with columns ``t`` and ``latency_s`` (others are ignored),
  interpolated linearly in time and held at its first and last values outside its range.

Bounds, checked before any work starts (a ``ValueError`` names the spec or the file, row and value):

- a spec is at most ``MAX_SPEC_CHARS`` (4096) characters without control characters; an empty spec
  is an error (write ``none`` for no latency);
- every latency is in [0, ``MAX_LATENCY_S``] = [0, 10] s;
- every period and duration is in [``MIN_PERIOD_S``, ``MAX_PERIOD_S``] = [0.001, 1e6] s;
- ``frames``: LO <= HI integers, EVERY >= 1, RATE in [``MIN_RATE_HZ``, ``MAX_RATE_HZ``] = [1, 1000] Hz
  (so HI / RATE <= 10 s and EVERY / RATE within the period bounds);
- a trace file is at most ``MAX_TRACE_BYTES`` (32 MiB) and ``MAX_TRACE_ROWS`` (1,000,000) data rows of
  UTF-8 text without a byte-order mark or control characters; its times are strictly increasing in
  [0, ``MAX_TRACE_DURATION_S``] = [0, 1e6] s.

Random profiles (``steps``, ``frames``) draw lazily in O(1) memory: the value of redraw period ``i``
is the ``i``-th draw of the generator given to ``reset``, reached by jumping the PCG64 stream ahead
(``advance``) instead of storing earlier draws. Their values are the same as drawing them one after
another, so a realisation depends only on the seed, never on which times were asked for.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import check_csv_columns

MAX_SPEC_CHARS = 4096
MAX_LATENCY_S = 10.0
MIN_PERIOD_S = 1e-3
MAX_PERIOD_S = 1e6
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 1000.0
MAX_TRACE_BYTES = 32 * 1024 * 1024
MAX_TRACE_ROWS = 1_000_000
MAX_TRACE_COLUMNS = 64  # t, latency_s and a few notes: a row of millions of cells is refused before it is built
MAX_TRACE_DURATION_S = 1e6

SPEC_FORMS = ("none", "S", "const:S", "steps:LO-HI:PERIOD", "frames:LO-HI:EVERY@RATE", "sine:MEAN:AMP:PERIOD",
              "ramp:FROM-TO:SECONDS", "trace:PATH.csv")
SPEC_HELP = (
    "latency profile: none | S | const:S | steps:LO-HI:PERIOD (uniform in [LO,HI] s, redrawn every PERIOD s) | "
    "frames:LO-HI:EVERY@RATE (integer frames LO..HI of a RATE Hz loop, redrawn every EVERY frames; "
    "frames:9-21:60@30 is the original code, @60 the paper's reading) | sine:MEAN:AMP:PERIOD | "
    "ramp:FROM-TO:SECONDS | trace:PATH.csv (columns t, latency_s). Latencies 0..10 s, periods 0.001..1e6 s"
)

# ASCII digits only: Python's float() also reads Arabic-Indic or full-width digits, which no reader of
# the spec would take for the same number.
_DECIMAL = re.compile(r"(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_INTEGER = re.compile(r"\d{1,9}", re.ASCII)
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")  # tab, CR and LF are whitespace, not garbage


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

    def middle_constant_spec(self) -> str:
        """The constant latency in the middle of this profile's range (:func:`legacy_baseline_spec`), defined for the
        original's profiles only."""
        raise BadInput(f"setting {self.spec!r}: the legacy FIFO runs the BM baseline at a constant latency, defined "
                       "for 'steps:' and 'frames:' profiles (the original's); use --injection time for this profile")

    def __str__(self) -> str:
        return self.spec


# -- bounds shared by the profiles and the parser ------------------------------------------------


def check_latency_s(value: float, what: str = "latency") -> float:
    value = float(value)
    if not (math.isfinite(value) and 0.0 <= value <= MAX_LATENCY_S):
        raise BadInput(f"{what} {value!r} s is outside [0, {MAX_LATENCY_S:g}] s")
    return value


def check_period_s(value: float, what: str = "period") -> float:
    value = float(value)
    if not (math.isfinite(value) and MIN_PERIOD_S <= value <= MAX_PERIOD_S):
        raise BadInput(f"{what} {value!r} s is outside [{MIN_PERIOD_S:g}, {MAX_PERIOD_S:g}] s")
    return value


def _check_time_s(t_s: float) -> float:
    t_s = float(t_s)
    if not math.isfinite(t_s):
        raise BadInput(f"time {t_s!r} s is not finite")
    return t_s


def _period_index(t_s: float, period_s: float) -> int:
    # Snapshot times are multiples of the simulation step: absorb their float error at period edges.
    return int(math.floor(max(_check_time_s(t_s), 0.0) / period_s + 1e-9))


class _LazyUniformDraws:
    """The ``i``-th draw of a generator's stream, in O(1) memory and O(1) time per new index.

    PCG64's ``advance(n)`` jumps the state ``n`` 64-bit outputs ahead, and ``random``/``uniform``
    consume exactly one output per double, so jumping gives the values sequential draws would.
    Only the generator's starting state (a few integers) and the last draw are kept.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        bit_generator = rng.bit_generator
        if not isinstance(bit_generator, (np.random.PCG64, np.random.PCG64DXSM)):
            # No per-output jump ahead: derive a PCG64 stream from the caller's generator instead.
            bit_generator = np.random.PCG64(np.random.SeedSequence(rng.integers(0, 2**32, size=4)))
        self._start_state = bit_generator.state
        self._generator = np.random.Generator(type(bit_generator)())
        self._rewind()

    def _rewind(self) -> None:
        self._generator.bit_generator.state = self._start_state
        self._next_index = 0  # the index the next draw from the generator has
        self._index, self._value = -1, 0.0

    def uniform(self, index: int, low: float = 0.0, high: float = 1.0) -> float:
        """Draw ``index`` (0-based) of ``uniform(low, high)``; ``low`` and ``high`` must not change."""
        if index == self._index:
            return self._value
        if index < self._next_index:
            self._rewind()
        if index > self._next_index:
            # PCG64 has period 2**128: jumping by the index modulo the period is exact.
            self._generator.bit_generator.advance((index - self._next_index) % 2**128)
        self._value = float(self._generator.uniform(low, high))
        self._index, self._next_index = index, index + 1
        return self._value


# -- profiles ----------------------------------------------------------------------------------


@dataclass
class ConstantProfile(LatencyProfile):
    value_s: float
    spec: str = ""

    def __post_init__(self) -> None:
        self.value_s = check_latency_s(self.value_s)
        self.spec = self.spec or f"const:{self.value_s!r}"

    def latency_s(self, t_s: float) -> float:
        return self.value_s

    @property
    def max_latency_s(self) -> float:
        return self.value_s

    def middle_constant_spec(self) -> str:
        return self.spec


@dataclass
class StepsProfile(LatencyProfile):
    """Uniform in [low_s, high_s], redrawn every ``period_s``: draw ``i`` holds in period ``i``."""

    low_s: float
    high_s: float
    period_s: float
    spec: str = ""
    _draws: _LazyUniformDraws | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.low_s, self.high_s = check_latency_s(self.low_s, "range start"), check_latency_s(self.high_s, "range end")
        if self.high_s < self.low_s:
            raise BadInput(f"range end {self.high_s!r} s is below its start {self.low_s!r} s")
        self.period_s = check_period_s(self.period_s)
        self.spec = self.spec or f"steps:{self.low_s!r}-{self.high_s!r}:{self.period_s!r}"

    def reset(self, rng: np.random.Generator) -> None:
        self._draws = _LazyUniformDraws(rng)

    def latency_s(self, t_s: float) -> float:
        if self._draws is None:
            raise RuntimeError(f"{self.spec}: reset(rng) must be called before use")
        return self._draws.uniform(_period_index(t_s, self.period_s), self.low_s, self.high_s)

    @property
    def max_latency_s(self) -> float:
        return self.high_s

    def middle_constant_spec(self) -> str:
        return f"const:{(self.low_s + self.high_s) / 2:g}"


@dataclass
class FramesProfile(LatencyProfile):
    """The original PLM-Net profile: integer frames of a ``rate_hz`` loop, redrawn every ``every_frames``.

    Frame ``n`` of the loop is the one at ``t = n / rate_hz`` since reset; the draw for block
    ``n // every_frames`` is ``low + floor(u (high - low + 1))`` with ``u`` the block's uniform draw
    (one generator output per block, so blocks are reached by jumping ahead, as in ``steps``).
    """

    low_frames: int
    high_frames: int
    every_frames: int
    rate_hz: float
    spec: str = ""
    _draws: _LazyUniformDraws | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.rate_hz, (int, float)) and MIN_RATE_HZ <= self.rate_hz <= MAX_RATE_HZ):
            raise BadInput(f"loop rate {self.rate_hz!r} Hz is outside [{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz")
        for name in ("low_frames", "high_frames", "every_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise BadInput(f"{name} {value!r} must be a non-negative integer")
        if self.high_frames < self.low_frames:
            raise BadInput(f"frame range end {self.high_frames} is below its start {self.low_frames}")
        check_latency_s(self.high_frames / self.rate_hz, f"{self.high_frames} frames at {self.rate_hz:g} Hz =")
        if self.every_frames < 1:
            raise BadInput(f"redraw every {self.every_frames} frames: must be at least 1")
        check_period_s(self.every_frames / self.rate_hz, f"redraw period {self.every_frames} frames at {self.rate_hz:g} Hz =")
        self.spec = self.spec or f"frames:{self.low_frames}-{self.high_frames}:{self.every_frames}@{self.rate_hz:g}"

    def reset(self, rng: np.random.Generator) -> None:
        self._draws = _LazyUniformDraws(rng)

    def frames(self, t_s: float) -> int:
        """The latency in frames of the loop at time ``t_s`` since reset."""
        if self._draws is None:
            raise RuntimeError(f"{self.spec}: reset(rng) must be called before use")
        frame = _period_index(t_s, 1.0 / self.rate_hz)
        count = self.high_frames - self.low_frames + 1
        draw = self._draws.uniform(frame // self.every_frames)
        return self.low_frames + min(int(draw * count), count - 1)

    def latency_s(self, t_s: float) -> float:
        return self.frames(t_s) / self.rate_hz

    @property
    def max_latency_s(self) -> float:
        return self.high_frames / self.rate_hz

    def middle_constant_spec(self) -> str:
        return f"const:{(self.low_frames + self.high_frames) // 2 / self.rate_hz:g}"  # a whole frame count


@dataclass
class SineProfile(LatencyProfile):
    mean_s: float
    amplitude_s: float
    period_s: float
    spec: str = ""

    def __post_init__(self) -> None:
        self.mean_s = check_latency_s(self.mean_s, "mean")
        self.amplitude_s = check_latency_s(self.amplitude_s, "amplitude")
        if self.amplitude_s > self.mean_s:
            raise BadInput(f"amplitude {self.amplitude_s!r} s exceeds mean {self.mean_s!r} s; latency would be negative")
        check_latency_s(self.mean_s + self.amplitude_s, "crest (mean + amplitude)")
        self.period_s = check_period_s(self.period_s)
        self.spec = self.spec or f"sine:{self.mean_s!r}:{self.amplitude_s!r}:{self.period_s!r}"

    def latency_s(self, t_s: float) -> float:
        return self.mean_s + self.amplitude_s * math.sin(2 * math.pi * _check_time_s(t_s) / self.period_s)

    @property
    def max_latency_s(self) -> float:
        return self.mean_s + self.amplitude_s


@dataclass
class RampProfile(LatencyProfile):
    from_s: float
    to_s: float
    duration_s: float
    spec: str = ""

    def __post_init__(self) -> None:
        self.from_s, self.to_s = check_latency_s(self.from_s, "ramp start"), check_latency_s(self.to_s, "ramp end")
        self.duration_s = check_period_s(self.duration_s, "duration")
        self.spec = self.spec or f"ramp:{self.from_s!r}-{self.to_s!r}:{self.duration_s!r}"

    def latency_s(self, t_s: float) -> float:
        fraction = min(max(_check_time_s(t_s) / self.duration_s, 0.0), 1.0)
        return self.from_s + (self.to_s - self.from_s) * fraction

    @property
    def max_latency_s(self) -> float:
        return max(self.from_s, self.to_s)


@dataclass(eq=False)
class TraceProfile(LatencyProfile):
    t_s: np.ndarray
    values_s: np.ndarray
    spec: str = ""

    def latency_s(self, t_s: float) -> float:
        return float(np.interp(_check_time_s(t_s), self.t_s, self.values_s))

    @property
    def max_latency_s(self) -> float:
        return float(self.values_s.max())


# -- parsing -----------------------------------------------------------------------------------


class JitteredProfile(LatencyProfile):
    """A latency profile plus a uniform jitter of +-``jitter_s``, redrawn every ``period_s`` (seeded at reset)."""

    def __init__(self, base: str | LatencyProfile, jitter_s: float, period_s: float):
        self.base = parse_profile(base)
        self.jitter_s, self.period_s = jitter_s, period_s
        self.spec = f"{self.base.spec} +- {jitter_s:g} s every {period_s:g} s"
        self._draws: list[float] = []
        self._rng: np.random.Generator | None = None

    def reset(self, rng: np.random.Generator) -> None:
        self.base.reset(rng)
        self._rng = np.random.default_rng(rng.integers(0, 2**32, size=2))
        self._draws = []

    def latency_s(self, t_s: float) -> float:
        index = int(math.floor(max(t_s, 0.0) / self.period_s + 1e-9))
        while len(self._draws) <= index:  # drawn in index order whatever is asked: a realisation per seed
            self._draws.append(float(self._rng.uniform(-self.jitter_s, self.jitter_s)))
        return max(0.0, self.base.latency_s(t_s) + self._draws[index])

    @property
    def max_latency_s(self) -> float:
        return self.base.max_latency_s + self.jitter_s


def parse_profile(spec: str | LatencyProfile | float) -> LatencyProfile:
    """Parse a latency spec (module docstring); a ValueError quotes the offending text."""
    if isinstance(spec, LatencyProfile):
        return spec
    if isinstance(spec, (int, float, np.integer, np.floating)) and not isinstance(spec, (bool, np.bool_)):
        try:
            return ConstantProfile(float(spec))
        except OverflowError:
            raise BadInput(f"latency {str(spec)[:40]}...: too large a number of seconds") from None
        except ValueError as error:
            raise BadInput(f"latency {spec!r}: {error}") from None
    if not isinstance(spec, str):
        raise BadInput(f"latency spec {spec!r}: expected a string such as 'const:0.2'")
    if len(spec) > MAX_SPEC_CHARS:
        raise BadInput(f"latency spec {spec[:40]!r}...: {len(spec)} characters, more than the {MAX_SPEC_CHARS} allowed")
    control = _CONTROL.search(spec)
    if control:
        raise BadInput(f"latency spec {spec!r}: control character {control.group()!r} at position {control.start()}")
    text = spec.strip()
    if not text:
        raise BadInput(f"latency spec {spec!r} is empty; write 'none' or 'const:0' for no latency")
    if text == "none":
        text = "const:0"
    elif _DECIMAL.fullmatch(text):
        text = f"const:{text}"
    kind, _, rest = text.partition(":")
    parsers = {"const": _parse_const, "steps": _parse_steps, "frames": _parse_frames, "sine": _parse_sine,
               "ramp": _parse_ramp, "trace": _parse_trace}
    if kind not in parsers or not rest:
        raise BadInput(f"latency spec {spec!r}: expected one of {', '.join(SPEC_FORMS)}")
    try:
        profile = parsers[kind](rest, spec)
    except ValueError as error:
        message = str(error)
        raise BadInput(message if message.startswith("latency spec") else f"latency spec {spec!r}: {message}") from None
    profile.spec = text
    return profile


def _number(text: str, spec: str, what: str) -> float:
    if not _DECIMAL.fullmatch(text):
        raise BadInput(f"latency spec {spec!r}: {what} {text!r} is not a plain non-negative decimal number")
    value = float(text)
    if not math.isfinite(value):  # e.g. 1e999
        raise BadInput(f"latency spec {spec!r}: {what} {text!r} is not finite")
    return value


def _integer(text: str, spec: str, what: str) -> int:
    if not _INTEGER.fullmatch(text):
        raise BadInput(f"latency spec {spec!r}: {what} {text!r} is not a whole number of at most 9 digits")
    return int(text)


def _split_range(text: str, spec: str, what: str) -> tuple[str, str]:
    # Split at the first '-' that is not a sign (leading, or an exponent's as in 1e-05).
    split = next((i for i, char in enumerate(text) if char == "-" and i > 0 and text[i - 1] not in "eE"), None)
    if split is None:
        raise BadInput(f"latency spec {spec!r}: {what} {text!r} must look like LO-HI")
    return text[:split], text[split + 1:]


def _range(text: str, spec: str, what: str) -> tuple[float, float]:
    low, high = _split_range(text, spec, what)
    return _number(low, spec, f"{what} start"), _number(high, spec, f"{what} end")


def _fields(rest: str, spec: str, count: int) -> list[str]:
    parts = rest.split(":")
    if len(parts) != count:
        raise BadInput(f"latency spec {spec!r}: expected {count} ':'-separated fields after the kind, got {len(parts)}")
    return parts


def _parse_const(rest: str, spec: str) -> LatencyProfile:
    (value,) = _fields(rest, spec, 1)
    return ConstantProfile(_number(value, spec, "latency"))


def _parse_steps(rest: str, spec: str) -> LatencyProfile:
    span, period = _fields(rest, spec, 2)
    low_s, high_s = _range(span, spec, "range")
    return StepsProfile(low_s, high_s, _number(period, spec, "period"))


def _parse_frames(rest: str, spec: str) -> LatencyProfile:
    span, timing = _fields(rest, spec, 2)
    low, high = _split_range(span, spec, "frame range")
    every, at, rate = timing.partition("@")
    if not at:
        raise BadInput(f"latency spec {spec!r}: {timing!r} must look like EVERY@RATE (frames @ loop Hz), e.g. 60@30")
    return FramesProfile(_integer(low, spec, "frame range start"), _integer(high, spec, "frame range end"),
                         _integer(every, spec, "redraw interval"), _number(rate, spec, "loop rate"))


def _parse_sine(rest: str, spec: str) -> LatencyProfile:
    mean, amplitude, period = _fields(rest, spec, 3)
    return SineProfile(_number(mean, spec, "mean"), _number(amplitude, spec, "amplitude"), _number(period, spec, "period"))


def _parse_ramp(rest: str, spec: str) -> LatencyProfile:
    span, duration = _fields(rest, spec, 2)
    from_s, to_s = _range(span, spec, "range")
    return RampProfile(from_s, to_s, _number(duration, spec, "duration"))


def _parse_trace(rest: str, spec: str) -> LatencyProfile:
    t_s, values_s = read_trace(Path(rest))
    return TraceProfile(t_s, values_s)


# -- trace files ---------------------------------------------------------------------------------


def read_trace(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a latency trace CSV (columns ``t``, ``latency_s``); errors name the file, row and value."""
    path = Path(path)
    raw = _read_bounded(path)
    if raw.startswith(b"\xef\xbb\xbf"):
        raise BadInput(f"trace file {str(path)!r}: row 1 starts with a UTF-8 byte-order mark (BOM); "
                         "save it as UTF-8 without BOM")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        row = raw.count(b"\n", 0, error.start) + 1
        raise BadInput(f"trace file {str(path)!r}: row {row}: byte {raw[error.start]:#04x} at offset {error.start} "
                         "is not UTF-8 text (a binary file?)") from None
    control = _CONTROL.search(text)
    if control:
        row = text.count("\n", 0, control.start()) + 1
        raise BadInput(f"trace file {str(path)!r}: row {row}: control character {control.group()!r} "
                         "(a binary file?)")
    return _parse_trace_rows(path, text)


def _read_bounded(path: Path) -> bytes:
    try:
        if not path.is_file():
            what = "does not exist" if not path.exists() else "is not a regular file"
            raise BadInput(f"trace file {str(path)!r} {what}")
        size = path.stat().st_size
        if size > MAX_TRACE_BYTES:
            raise BadInput(f"trace file {str(path)!r}: {size} bytes, more than the {MAX_TRACE_BYTES} allowed")
        with open(path, "rb") as handle:
            raw = handle.read(MAX_TRACE_BYTES + 1)  # the file may grow after stat
    except OSError as error:
        raise BadInput(f"trace file {str(path)!r}: cannot be read ({error.strerror or error})") from None
    if len(raw) > MAX_TRACE_BYTES:
        raise BadInput(f"trace file {str(path)!r}: more than the {MAX_TRACE_BYTES} bytes allowed")
    return raw


def _parse_trace_rows(path: Path, text: str) -> tuple[np.ndarray, np.ndarray]:
    name = repr(str(path))
    check_csv_columns(text, f"trace file {name}", MAX_TRACE_COLUMNS)
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = [column.strip() for column in next(reader)]
    except StopIteration:
        raise BadInput(f"trace file {name}: empty (expected a header row 't,latency_s')") from None
    except csv.Error as error:
        raise BadInput(f"trace file {name}: row 1: {error}") from None
    missing = [column for column in ("t", "latency_s") if column not in header]
    if missing:
        raise BadInput(f"trace file {name}: row 1: missing columns {missing} (header: {header})")
    duplicated = sorted({column for column in ("t", "latency_s") if header.count(column) > 1})
    if duplicated:
        raise BadInput(f"trace file {name}: row 1: columns {duplicated} appear more than once")
    t_column, value_column = header.index("t"), header.index("latency_s")
    times, values = [], []
    try:
        for cells in reader:
            if not cells or all(not cell.strip() for cell in cells):
                continue  # blank lines carry no data
            row = reader.line_num
            if len(times) >= MAX_TRACE_ROWS:
                raise BadInput(f"trace file {name}: row {row}: more than the {MAX_TRACE_ROWS} data rows allowed")
            t = _trace_number(name, row, "t", cells, t_column)
            latency = _trace_number(name, row, "latency_s", cells, value_column)
            if t > MAX_TRACE_DURATION_S:
                raise BadInput(f"trace file {name}: row {row}, column 't': {t!r} s is beyond the "
                                 f"{MAX_TRACE_DURATION_S:g} s allowed")
            if times and t <= times[-1]:
                raise BadInput(f"trace file {name}: row {row}, column 't': {t!r} does not increase "
                                 f"(previous {times[-1]!r})")
            if latency > MAX_LATENCY_S:
                raise BadInput(f"trace file {name}: row {row}, column 'latency_s': {latency!r} s is beyond the "
                                 f"{MAX_LATENCY_S:g} s allowed")
            times.append(t)
            values.append(latency)
    except csv.Error as error:
        raise BadInput(f"trace file {name}: row {reader.line_num}: {error}") from None
    if not times:
        raise BadInput(f"trace file {name}: no rows after the header")
    return np.array(times), np.array(values)


def _trace_number(name: str, row: int, column: str, cells: list[str], index: int) -> float:
    text = cells[index].strip() if index < len(cells) else ""
    where = f"trace file {name}: row {row}, column {column!r}"
    if not text:
        raise BadInput(f"{where}: missing value")
    try:
        value = float(text)
    except ValueError:
        raise BadInput(f"{where}: {text[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise BadInput(f"{where}: {text!r} is not finite")
    if value < 0:
        raise BadInput(f"{where}: {text!r} is negative")
    if not _DECIMAL.fullmatch(text.lstrip("+")):
        raise BadInput(f"{where}: {text[:40]!r} is not a plain decimal number")
    return value


def legacy_baseline_spec(spec: str) -> str:
    """The constant latency the BM baseline of setting ``spec`` runs at under the legacy FIFO.

    In the original code's time-variant run (``run_neural_..._synced_rand.py``) the random delta was drawn,
    published and printed, but the BM's input buffer was cut to the *configured* constant delta: the BM
    never saw a varying latency. Which constant the configuration held is not in the published code; the
    paper's time-variant BM MAE (0.3336) equals its 0.25-s BM MAE (0.3347) to 0.3%, which is what a BM run
    at the middle of 9..21 frames (15: 0.25 s in the paper's 60-fps reading) gives. The middle of the
    profile's range is taken (:meth:`LatencyProfile.middle_constant_spec`); a constant setting is its own.
    """
    return parse_profile(spec).middle_constant_spec()


def check_specs(specs, where: str = "") -> None:
    """Refuse (BadInput) the first of ``specs`` that is not a latency spec, its message led by ``where`` (the field
    or file it came from): specs are checked where they enter and parsed where a run is made of them."""
    for spec in specs:
        try:
            parse_profile(spec)
        except ValueError as exc:
            if not where:
                raise
            raise BadInput(f"{where}: {exc}") from None


# -- camera processing delays (the lane EKF's camera) ----------------------------------------

MAX_CAMERA_DELAY_S = 5.0


class PerFrameDelay(LatencyProfile):
    """A new processing delay for every frame, uniform in [low_s, high_s]: call once per frame."""

    def __init__(self, low_s: float, high_s: float, spec: str = ""):
        self.low_s, self.high_s, self.spec = low_s, high_s, spec
        self._rng: np.random.Generator | None = None

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng

    def latency_s(self, t_s: float) -> float:
        if self._rng is None:
            raise RuntimeError(f"{self.spec}: reset(rng) must be called before use")
        return float(self._rng.uniform(self.low_s, self.high_s))

    @property
    def max_latency_s(self) -> float:
        return self.high_s


def parse_camera_delay(spec: str | float | LatencyProfile) -> LatencyProfile:
    """A camera processing delay: ``frame:LO-HI`` (per-frame uniform) or any kit latency profile."""
    if isinstance(spec, str) and spec.strip().startswith("frame:"):
        text = spec.strip()
        low_s, high_s = _range(text.partition(":")[2], text, "range")
        if high_s < low_s:
            raise ValueError(f"camera delay {spec!r}: range ends below its start")
        profile: LatencyProfile = PerFrameDelay(low_s, high_s, text)
    else:
        profile = parse_profile(spec)
    if profile.max_latency_s > MAX_CAMERA_DELAY_S:
        raise ValueError(f"camera delay {profile.spec!r}: reaches {profile.max_latency_s} s; at most "
                         f"{MAX_CAMERA_DELAY_S} s is accepted")
    return profile
