"""Recordings: what a car did, in the simulator's units and sign conventions.

File format (CSV with a header row; column order free, unknown columns ignored):

========== ======== ============================================================================
column     unit     meaning
========== ======== ============================================================================
t          s        time, strictly increasing (near-uniform sampling; jitter is resampled)
steer      rad      front-wheel angle as commanded; positive steers left (raises the heading)
speed      m/s      speed of the reference point (centre of gravity)
x, y       m        position of the reference point; world frame x right, y up
heading    rad      yaw angle, counter-clockwise from +x; may wrap at +-pi
yaw_rate   rad/s    optional: measured yaw rate (gyro); positive turning left
lat_accel  m/s^2    optional: measured lateral acceleration; positive to the left
========== ======== ============================================================================

Optional JSON sidecar with the same stem (``run.csv`` -> ``run.json``) describing the car:
``wheelbase_m``, ``cg_to_front_m``, ``cg_to_rear_m``, ``mass_kg``, ``yaw_inertia_kgm2``.
Without it the car is the simulator's own (highway-env: 5 m long, reference point in the middle,
lf = lr = 2.5 m). With only ``wheelbase_m`` the reference point is taken in the middle, as in the
simulator; with the wheelbase and one of ``cg_to_front_m``/``cg_to_rear_m`` the other follows.

Bounds, checked before any work: a file of at most ``MAX_BYTES`` (512 MiB), ``MAX_COLUMNS`` (2,000)
columns and lines of ``MAX_LINE_CHARS`` (1,000,000) characters, of which only the recording's own
columns are stored; at most ``MAX_ROWS`` (150,000) data rows, 10 s to 4 h of data, a median sampling
interval of 1 ms to 0.2 s (1 kHz to 5 Hz), a sidecar of at most 64 KiB with values within
``SIDECAR_RANGES`` (wheelbase 0.05-20 m, mass 0.05-100,000 kg, yaw inertia 0.2-5 x m a b).

Bad input raises ``ValueError`` naming the column and file line (line 1 is the header); data that
is still usable loads with human-readable ``warnings`` attached to the :class:`Recording`.
:func:`read_sim_log` maps the simulator's own per-step logs (any CSV with columns for time, pose,
speed and the steering command) onto the same type, so a sim run and a recording compare directly.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import JSON_MARKER_KEY, JsonLimits, file_kind, json_text, load_json, write_outputs
from plm_highway.io.bounded import parse_float_text
from plm_highway.vehicle.kinematic import HIGHWAY_ENV_VEHICLE, KinematicBicycleParams

REQUIRED_COLUMNS = ("t", "steer", "speed", "x", "y", "heading")
OPTIONAL_COLUMNS = ("yaw_rate", "lat_accel")
SIDECAR_KEYS = ("wheelbase_m", "cg_to_front_m", "cg_to_rear_m", "mass_kg", "yaw_inertia_kgm2")

MIN_DURATION_S = 10.0
# Bounds checked before any work (a diagnosis allocates a few arrays of this length per candidate
# tire; split longer recordings). 150,000 rows is 50 min at 50 Hz.
MAX_ROWS = 150_000
# The file itself: bytes, columns and characters per line, checked before anything is stored (only
# the recording's own columns are kept; a wide log of 150,000 rows and 2,000 columns fits).
MAX_BYTES = 512 * 1024**2
MAX_COLUMNS = 2_000
MAX_LINE_CHARS = 1_000_000
MAX_SIDECAR_BYTES = 64 * 1024
MAX_DURATION_S = 4 * 3600.0
# Median sampling interval: 1 ms (1 kHz) to 0.2 s (5 Hz; slower sampling aliases the steering).
MIN_INTERVAL_S = 0.001
MAX_INTERVAL_S = 0.2
# Sidecar values a car can have (0.05 m: a 1:43 scale model; 20 m: an articulated bus).
SIDECAR_RANGES = {"wheelbase_m": (0.05, 20.0), "cg_to_front_m": (0.005, 20.0), "cg_to_rear_m": (0.005, 20.0),
                  "mass_kg": (0.05, 100_000.0), "yaw_inertia_kgm2": (1e-5, 2e6)}
# Yaw inertia over m a b (radius of gyration over the axle distances): ~1 for real cars.
INERTIA_RATIO_RANGE = (0.2, 5.0)
# A front-wheel angle above 1 rad (57 deg) is not a road car's; sustained, it means degrees.
STEER_DEGREES_THRESHOLD_RAD = 1.0
STEER_DEGREES_SUSTAINED_S = 0.5
# Sampling jitter above this fraction of the median interval is resampled onto a uniform grid.
JITTER_TOLERANCE = 0.05
# Gaps longer than this many intervals are interpolated but left out of every fit and score.
GAP_INTERVALS = 5.0
# A heading step this far from the yaw rate's integral (or, without a yaw rate, implying a yaw rate
# no car makes) is a localisation glitch; samples this close to one are not scored.
HEADING_JUMP_RAD = 0.2
MAX_PLAUSIBLE_YAW_RATE_RADPS = 3.0
# The window over which a rate is read from an angle (the heading's rate, by a Savitzky-Golay derivative).
HEADING_DERIVATIVE_WINDOW_S = 0.5
# Glitches are rare: a yaw rate that disagrees with this share of the heading's steps is no reference.
MAX_GLITCH_FRACTION = 0.02
# A glitch also stands this many standard deviations of the heading's own step noise out of it (a noisy
# heading's steps are not glitches).
GLITCH_NOISE_SIGMAS = 6.0
JUMP_EXCLUDE_S = 1.0
# The speed floor: below it a sample is not scored (the car barely turns whatever it steers, and
# the slip models divide by the speed). It scales with the car and with how it was driven:
#   floor = max(min(0.4 /s x wheelbase, 0.25 x median moving speed), 0.02 /s x wheelbase),
# "moving" meaning faster than 0.02 wheelbases per second. For highway-env's 5-m car at highway
# speeds this is 2 m/s (the old fixed floor); for a 0.33-m 1:10 car at ~1.2 m/s it is 0.13 m/s.
SPEED_FLOOR_WHEELBASES_PER_S = 0.4
SPEED_FLOOR_MEDIAN_FRACTION = 0.25
STANDSTILL_WHEELBASES_PER_S = 0.02


@dataclass(frozen=True)
class VehicleGeometry:
    """The car of a recording; ``mass_kg`` and ``yaw_inertia_kgm2`` are None when unknown."""

    cg_to_front_m: float = HIGHWAY_ENV_VEHICLE.cg_to_front_m
    cg_to_rear_m: float = HIGHWAY_ENV_VEHICLE.cg_to_rear_m
    mass_kg: float | None = None
    yaw_inertia_kgm2: float | None = None
    source: str = "simulator"

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m

    @property
    def kinematic(self) -> KinematicBicycleParams:
        return KinematicBicycleParams(self.cg_to_front_m, self.cg_to_rear_m)

    @property
    def inertia_known(self) -> bool:
        return self.mass_kg is not None and self.yaw_inertia_kgm2 is not None

    @property
    def yaw_inertia_per_kg_m2(self) -> float:
        """Iz / m; without both numbers, the radius-of-gyration rule Iz / m = a * b."""
        if self.inertia_known:
            return float(self.yaw_inertia_kgm2) / float(self.mass_kg)
        return self.cg_to_front_m * self.cg_to_rear_m

    def sidecar(self) -> dict[str, float]:
        out = {"wheelbase_m": self.wheelbase_m, "cg_to_front_m": self.cg_to_front_m,
               "cg_to_rear_m": self.cg_to_rear_m}
        if self.mass_kg is not None:
            out["mass_kg"] = self.mass_kg
        if self.yaw_inertia_kgm2 is not None:
            out["yaw_inertia_kgm2"] = self.yaw_inertia_kgm2
        return out


SIMULATOR_VEHICLE = VehicleGeometry()


@dataclass(frozen=True)
class Recording:
    """Uniformly sampled signals of one run (arrays of equal length ``n``)."""

    t_s: np.ndarray
    steer_rad: np.ndarray
    speed_mps: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray  # unwrapped (continuous)
    yaw_rate_radps: np.ndarray | None = None
    lat_accel_mps2: np.ndarray | None = None
    vehicle: VehicleGeometry = SIMULATOR_VEHICLE
    name: str = "recording"
    # False where a sample was interpolated across a gap or the car is too slow to score.
    usable: np.ndarray | None = None
    warnings: tuple[str, ...] = field(default=())
    # The rows as recorded ("t" and the optional gyro "yaw_rate") when they were resampled onto the
    # uniform grid: interpolation averages and colours the noise, so the noise and the whiteness of
    # what a fit leaves are measured on these.
    raw: dict[str, np.ndarray] | None = field(default=None, compare=False)

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def dt_s(self) -> float:
        return float((self.t_s[-1] - self.t_s[0]) / (self.n - 1))

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @cached_property
    def speed_floor_mps(self) -> float:
        """Samples slower than this are not scored (see SPEED_FLOOR_WHEELBASES_PER_S)."""
        wheelbase = self.vehicle.wheelbase_m
        standstill = STANDSTILL_WHEELBASES_PER_S * wheelbase
        moving = self.speed_mps[self.speed_mps > standstill]
        median = float(np.median(moving)) if moving.size else 0.0
        return max(min(SPEED_FLOOR_WHEELBASES_PER_S * wheelbase, SPEED_FLOOR_MEDIAN_FRACTION * median), standstill)

    @property
    def tire_min_speed_mps(self) -> float:
        """The tire models hold the speed at this or above (half the floor, at most 0.5 m/s)."""
        return min(0.5, 0.5 * self.speed_floor_mps)

    @property
    def usable_mask(self) -> np.ndarray:
        mask = np.ones(self.n, bool) if self.usable is None else self.usable.copy()
        return mask & (self.speed_mps > self.speed_floor_mps)

    def columns(self) -> dict[str, np.ndarray]:
        """The signals under their CSV names (optional columns only when recorded)."""
        out = {"t": self.t_s, "steer": self.steer_rad, "speed": self.speed_mps, "x": self.x_m, "y": self.y_m,
               "heading": self.heading_rad}
        if self.yaw_rate_radps is not None:
            out["yaw_rate"] = self.yaw_rate_radps
        if self.lat_accel_mps2 is not None:
            out["lat_accel"] = self.lat_accel_mps2
        return out

    @property
    def is_uniform(self) -> bool:
        """Sampled uniformly, up to the jitter the reader accepts without resampling."""
        steps = np.diff(self.t_s)
        return bool(np.all(np.abs(steps - self.dt_s) <= JITTER_TOLERANCE * self.dt_s + 1e-12))

    def slice(self, start: int, stop: int) -> Recording:
        """Samples ``start:stop`` (for windows and lessons)."""
        def cut(a):
            return None if a is None else a[start:stop].copy()
        return replace(self, raw=None, t_s=cut(self.t_s), steer_rad=cut(self.steer_rad), speed_mps=cut(self.speed_mps),
                       x_m=cut(self.x_m), y_m=cut(self.y_m), heading_rad=cut(self.heading_rad),
                       yaw_rate_radps=cut(self.yaw_rate_radps), lat_accel_mps2=cut(self.lat_accel_mps2),
                       usable=cut(self.usable))


# ----------------------------------------------------------------------------------------------
# Reading


def _lines(handle, path: Path):
    """The file's lines, each at most ``MAX_LINE_CHARS`` long (a longer one is refused before it is split)."""
    number = 0
    while True:
        line = handle.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
            raise ValueError(f"{path}: line {number} is longer than {MAX_LINE_CHARS:,} characters (the limit)")
        yield line


def _read_columns(path: Path, wanted: set[str] | None = None) -> tuple[list[str], dict[str, list[str]]]:
    """Header and the raw text of the ``wanted`` columns (all when None); a BOM is accepted.

    Bounded before and while reading: at most ``MAX_BYTES`` bytes, ``MAX_COLUMNS`` columns, lines
    of ``MAX_LINE_CHARS`` and ``MAX_ROWS`` data rows; columns not wanted are never stored.
    """
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise ValueError(f"{path}: {size:,} bytes; at most {MAX_BYTES:,} are accepted (the limit; keep only the "
                         "needed columns or split the recording)")
    line_no = 1
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(_lines(fh, path))
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise ValueError(f"{path}: the file is empty (expected a CSV header)") from None
            if len(header) > MAX_COLUMNS:
                raise ValueError(f"{path}: {len(header):,} columns in the header; at most {MAX_COLUMNS:,} are "
                                 "accepted (the limit)")
            if len(set(header)) != len(header):
                dupes = sorted({h for h in header if header.count(h) > 1})
                raise ValueError(f"{path}: duplicate column(s) {', '.join(dupes)} in the header")
            keep = [(i, h) for i, h in enumerate(header) if wanted is None or h in wanted]
            columns: dict[str, list[str]] = {h: [] for _, h in keep}
            rows = 0
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise ValueError(f"{path}: line {line_no} has {len(row)} fields, the header has {len(header)}")
                rows += 1
                if rows > MAX_ROWS:
                    raise ValueError(f"{path}: more than {MAX_ROWS:,} data rows (the limit; split the recording)")
                for i, h in keep:
                    columns[h].append(row[i])
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text CSV (bytes that are not UTF-8 near line {line_no + 1})") from None
    except csv.Error as exc:
        raise ValueError(f"{path}: line {line_no + 1}: not readable as CSV ({exc})") from None
    return header, columns


def _parse_column(path: Path, name: str, values: list[str], line_numbers: np.ndarray) -> np.ndarray:
    out = np.empty(len(values))
    for i, text in enumerate(values):
        try:  # digits 0-9 only, no '_' (float() reads '1_0' as 10 and Arabic-Indic digits as numbers)
            out[i] = parse_float_text(text, "", non_finite=True)
        except BadInput as exc:
            raise ValueError(f"{path}: column '{name}' line {line_numbers[i]}: {text!r} is not a number "
                             f"({str(exc).removeprefix(': ')})") from None
    return out


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def read_sidecar(path: Path) -> tuple[VehicleGeometry, list[str]]:
    """The car of a recording from its JSON sidecar, and warnings (e.g. unknown keys)."""
    warnings: list[str] = []
    # Bounded: size, nesting depth and node count checked, so a hostile sidecar is refused, never recursed into.
    data = load_json(path, JsonLimits(max_bytes=MAX_SIDECAR_BYTES, max_depth=8, max_nodes=10_000),
                     what="vehicle sidecar (JSON)")
    if not isinstance(data, dict):
        # Bad input, not a programming error: ValueError is what the CLI reports as "error: ..." (exit 2).
        raise ValueError(f"{path}: expected a JSON object with keys {', '.join(SIDECAR_KEYS)}")
    unknown = sorted(set(data) - set(SIDECAR_KEYS) - {JSON_MARKER_KEY})
    if unknown:
        warnings.append(f"{path.name}: unknown key(s) {', '.join(unknown)} ignored "
                        f"(known: {', '.join(SIDECAR_KEYS)})")
    values: dict[str, float] = {}
    for key in SIDECAR_KEYS:
        if key not in data or data[key] is None:
            continue
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ValueError(f"{path}: '{key}' must be a positive number, got {value!r}")
        lo, hi = SIDECAR_RANGES[key]
        if not lo <= value <= hi:
            raise ValueError(f"{path}: '{key}' = {value:g} is outside the accepted range {lo:g}-{hi:g}")
        values[key] = float(value)
    wheelbase = values.get("wheelbase_m")
    front = values.get("cg_to_front_m")
    rear = values.get("cg_to_rear_m")
    if front is not None and rear is not None:
        if wheelbase is not None and abs(front + rear - wheelbase) > 0.01:
            raise ValueError(f"{path}: cg_to_front_m + cg_to_rear_m = {front + rear:.3f} m "
                             f"but wheelbase_m = {wheelbase:.3f} m")
    elif wheelbase is not None:
        if front is None and rear is None:
            front = rear = wheelbase / 2  # the simulator's convention: reference point in the middle
        elif front is not None:
            rear = wheelbase - front
        else:
            front = wheelbase - rear
        if front <= 0 or rear <= 0:
            raise ValueError(f"{path}: the centre of gravity lies outside the wheelbase")
    elif front is not None or rear is not None:
        raise ValueError(f"{path}: give wheelbase_m or both cg_to_front_m and cg_to_rear_m")
    else:
        front, rear = SIMULATOR_VEHICLE.cg_to_front_m, SIMULATOR_VEHICLE.cg_to_rear_m
        warnings.append(f"{path.name}: no geometry given; using the simulator's (lf = lr = 2.5 m)")
    wheelbase_range = SIDECAR_RANGES["wheelbase_m"]
    if not wheelbase_range[0] <= front + rear <= wheelbase_range[1]:
        raise ValueError(f"{path}: cg_to_front_m + cg_to_rear_m = {front + rear:g} m is outside the accepted "
                         f"wheelbase range {wheelbase_range[0]:g}-{wheelbase_range[1]:g} m")
    mass, inertia = values.get("mass_kg"), values.get("yaw_inertia_kgm2")
    if mass is not None and inertia is not None:
        ratio = inertia / (mass * front * rear)
        if not INERTIA_RATIO_RANGE[0] <= ratio <= INERTIA_RATIO_RANGE[1]:
            raise ValueError(f"{path}: 'yaw_inertia_kgm2' = {inertia:g} is {ratio:.3g} x mass_kg x cg_to_front_m x "
                             f"cg_to_rear_m; a car's is {INERTIA_RATIO_RANGE[0]:g}-{INERTIA_RATIO_RANGE[1]:g} x")
    geometry = VehicleGeometry(cg_to_front_m=front, cg_to_rear_m=rear, mass_kg=mass,
                               yaw_inertia_kgm2=inertia, source=str(path))
    return geometry, warnings


def _check_times(path: Path, t: np.ndarray, line_numbers: np.ndarray) -> None:
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = _first_bad(steps <= 0) + 1
        kind = "duplicate" if steps[i - 1] == 0 else "decreasing"
        raise ValueError(f"{path}: column 't' is not strictly increasing: {kind} time {t[i]:.6g} s on line "
                         f"{line_numbers[i]} (previous line {line_numbers[i - 1]}: {t[i - 1]:.6g} s)")
    if t[-1] - t[0] < MIN_DURATION_S:
        raise ValueError(f"{path}: only {t[-1] - t[0]:.2f} s of data; at least {MIN_DURATION_S:.0f} s are needed "
                         "to fit and hold out")
    if t[-1] - t[0] > MAX_DURATION_S:
        raise ValueError(f"{path}: {t[-1] - t[0]:.6g} s of data; at most {MAX_DURATION_S:.0f} s are accepted "
                         f"(column 't' from line {line_numbers[0]} to {line_numbers[-1]}; split the recording)")
    interval = float(np.median(steps))
    if not MIN_INTERVAL_S <= interval <= MAX_INTERVAL_S:
        raise ValueError(f"{path}: column 't': median sampling interval {interval:.6g} s ({1 / interval:.4g} Hz); "
                         f"accepted {MIN_INTERVAL_S:g}-{MAX_INTERVAL_S:g} s ({1 / MAX_INTERVAL_S:g}-"
                         f"{1 / MIN_INTERVAL_S:g} Hz)")
    grid_rows = (t[-1] - t[0]) / interval + 1
    if grid_rows > MAX_ROWS:
        raise ValueError(f"{path}: resampled at its median interval {interval:.4g} s the recording has "
                         f"{grid_rows:,.0f} rows; at most {MAX_ROWS:,} are accepted (gaps or a split recording?)")


def _check_steer_units(path: Path, t: np.ndarray, steer: np.ndarray, line_numbers: np.ndarray,
                       warnings: list[str]) -> None:
    big = np.abs(steer) > STEER_DEGREES_THRESHOLD_RAD
    if not big.any():
        return
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
    seconds = float(dt[big].sum())
    first = _first_bad(big)
    if seconds >= STEER_DEGREES_SUSTAINED_S:
        raise ValueError(f"{path}: column 'steer' looks like degrees: |steer| > {STEER_DEGREES_THRESHOLD_RAD:g} rad "
                         f"for {seconds:.1f} s (first on line {line_numbers[first]}: {steer[first]:g}); "
                         "give the front-wheel angle in radians")
    warnings.append(f"column 'steer' exceeds {STEER_DEGREES_THRESHOLD_RAD:g} rad briefly ({int(big.sum())} rows, "
                    f"first on line {line_numbers[first]}); kept as radians")


def _heading_in_degrees(heading: np.ndarray, t: np.ndarray) -> bool:
    """Degrees betray themselves by wrapping at +-180 or by turning faster than any car (in rad/s)."""
    if np.max(np.abs(heading)) <= math.pi + 0.05:
        return False
    steps = np.abs(np.diff(heading))
    wraps_at_180 = np.any((steps > 300) & (steps < 420)) and not np.any((steps > 5.5) & (steps < 7.0))
    rate = np.abs(np.diff(np.unwrap(heading, period=360.0))) / np.diff(t)
    return bool(wraps_at_180 or np.percentile(rate, 95) > MAX_PLAUSIBLE_YAW_RATE_RADPS)


def _uniform_grid(t: np.ndarray, warnings: list[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """A uniform time grid for the samples, and a mask of grid points inside long gaps (or None)."""
    steps = np.diff(t)
    dt = float(np.median(steps))
    if np.max(np.abs(steps - dt)) <= JITTER_TOLERANCE * dt:
        return t, None
    n = round((t[-1] - t[0]) / dt) + 1
    dt = (t[-1] - t[0]) / (n - 1)  # the median interval, adjusted so the grid ends on the last sample
    grid = t[0] + dt * np.arange(n)
    grid[-1] = t[-1]
    gaps = np.flatnonzero(steps > GAP_INTERVALS * dt)
    usable = np.ones(n, bool)
    for g in gaps:
        usable &= ~((grid > t[g]) & (grid < t[g + 1]))
    message = f"sampling is not uniform (intervals {steps.min():.4g}-{steps.max():.4g} s); resampled at {dt:.4g} s"
    if len(gaps):
        message += (f"; {len(gaps)} gap(s) longer than {GAP_INTERVALS * dt:.3g} s (longest {steps.max():.3g} s) "
                    "are interpolated and left out of every fit and score")
    warnings.append(message)
    return grid, (usable if len(gaps) else None)


def _plausible_yaw_rate(steer: np.ndarray, speed: np.ndarray, wheelbase_m: float) -> float:
    """The fastest yaw rate this car plausibly makes: twice what its steering and speed give
    kinematically, and at least ``MAX_PLAUSIBLE_YAW_RATE_RADPS`` (a small car turns faster)."""
    kinematic = np.abs(speed) * np.abs(np.tan(np.clip(steer, -1.2, 1.2))) / wheelbase_m
    return max(MAX_PLAUSIBLE_YAW_RATE_RADPS, 2.0 * float(np.max(kinematic)))


def _step_noise_rad(heading: np.ndarray) -> float:
    """The standard deviation of the heading's step-to-step white noise, from its second differences
    (robust: the car's own turning and rare glitches barely move their median absolute deviation)."""
    if heading.shape[0] < 3:
        return 0.0
    second = np.diff(heading, 2)
    # white noise of std s: a step's is s*sqrt(2), a second difference's s*sqrt(6)
    return 1.4826 * float(np.median(np.abs(second - np.median(second)))) * math.sqrt(2.0 / 6.0)


def _heading_jumps(heading: np.ndarray, yaw_rate: np.ndarray | None, t: np.ndarray,
                   line_numbers: np.ndarray, warnings: list[str],
                   max_yaw_rate: float = MAX_PLAUSIBLE_YAW_RATE_RADPS) -> np.ndarray:
    """Indices of heading steps a car cannot make: not matched by the yaw rate (when recorded),
    or faster than ``max_yaw_rate``. Localisation glitches, not vehicle motion."""
    dt = np.diff(t)
    step = np.diff(heading)
    noise_rad = GLITCH_NOISE_SIGMAS * _step_noise_rad(heading)
    bad = np.zeros(0, int)
    if yaw_rate is not None:
        bad = np.flatnonzero(np.abs(step - 0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * dt)
                             > max(HEADING_JUMP_RAD, noise_rad))
        against = "not matched by yaw_rate"
    if yaw_rate is None or len(bad) > MAX_GLITCH_FRACTION * len(step):
        # Without a gyro, or with one that disagrees with the heading throughout (its units or sign;
        # the consistency checks name it): glitches are steps no car makes.
        bad = np.flatnonzero(np.abs(step) > max_yaw_rate * dt + max(HEADING_JUMP_RAD / 4, noise_rad))
        against = f"faster than {max_yaw_rate:.3g} rad/s"
    if len(bad):
        i = bad[0] + 1
        warnings.append(f"heading jumps by {step[bad[0]]:+.2f} rad on line {line_numbers[i]} (t={t[i]:.2f} s), "
                        f"{against} ({len(bad)} such step(s)); {JUMP_EXCLUDE_S:g} s around each are left out "
                        "of every fit and score")
    return bad


def recording_from_arrays(
    columns: dict[str, np.ndarray],
    vehicle: VehicleGeometry = SIMULATOR_VEHICLE,
    name: str = "recording",
    source: str = "<arrays>",
    line_numbers: np.ndarray | None = None,
    warnings: list[str] | None = None,
) -> Recording:
    """Validate named columns (the CSV names) and build a uniformly sampled :class:`Recording`."""
    path = Path(source)
    warnings = list(warnings or [])
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} "
                         f"(required: {', '.join(REQUIRED_COLUMNS)}; found: {', '.join(columns) or 'none'})")
    data = {k: np.asarray(v, dtype=float) for k, v in columns.items() if k in REQUIRED_COLUMNS + OPTIONAL_COLUMNS}
    n = len(data["t"])
    if line_numbers is None:
        line_numbers = np.arange(2, n + 2)
    if n < 3:
        raise ValueError(f"{path}: only {n} data row(s)")
    if n > MAX_ROWS:
        raise ValueError(f"{path}: {n:,} data rows; at most {MAX_ROWS:,} are accepted (split the recording)")
    for name_ in list(data):
        bad = ~np.isfinite(data[name_])
        if bad.any():
            i = _first_bad(bad)
            what = "NaN" if np.isnan(data[name_][i]) else "infinite"
            where = f"line {line_numbers[i]}"
            if name_ in OPTIONAL_COLUMNS:
                warnings.append(f"column '{name_}' is {what} on {where} ({int(bad.sum())} rows); "
                                f"the optional column is ignored")
                del data[name_]
                continue
            raise ValueError(f"{path}: column '{name_}' is {what} on {where} ({int(bad.sum())} bad row(s) in all)")
    t = data["t"]
    _check_times(path, t, line_numbers)
    _check_steer_units(path, t, data["steer"], line_numbers, warnings)
    if _heading_in_degrees(data["heading"], t):
        raise ValueError(f"{path}: column 'heading' looks like degrees (it wraps at +-180); give radians")
    heading = np.unwrap(data["heading"])
    if np.any(data["speed"] < 0):
        i = _first_bad(data["speed"] < 0)
        warnings.append(f"column 'speed' is negative from line {line_numbers[i]} (reversing); "
                        "such samples are not scored")
    jumps = _heading_jumps(heading, data.get("yaw_rate"), t, line_numbers, warnings,
                           _plausible_yaw_rate(data["steer"], data["speed"], vehicle.wheelbase_m))

    grid, usable = _uniform_grid(t, warnings)
    if len(jumps):
        usable = np.ones(len(grid), bool) if usable is None else usable
        for j in jumps:
            usable &= np.abs(grid - 0.5 * (t[j] + t[j + 1])) > JUMP_EXCLUDE_S

    def on_grid(values: np.ndarray | None) -> np.ndarray | None:
        if values is None:
            return None
        return values if grid is t else np.interp(grid, t, values)

    return Recording(
        t_s=grid,
        steer_rad=on_grid(data["steer"]),
        speed_mps=on_grid(data["speed"]),
        x_m=on_grid(data["x"]),
        y_m=on_grid(data["y"]),
        heading_rad=on_grid(heading),
        yaw_rate_radps=on_grid(data.get("yaw_rate")),
        lat_accel_mps2=on_grid(data.get("lat_accel")),
        vehicle=vehicle,
        name=name,
        usable=usable,
        warnings=tuple(warnings),
        raw=None if grid is t else {"t": t} | ({"yaw_rate": data["yaw_rate"]} if "yaw_rate" in data else {}),
    )


def read_recording(path: str | os.PathLike, sidecar: str | os.PathLike | None = None) -> Recording:
    """Read a recording CSV (and its sidecar ``<stem>.json`` when present); see the module docstring."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    sidecar_path = Path(sidecar) if sidecar is not None else path.with_suffix(".json")
    warnings: list[str] = []
    if sidecar_path.is_file():
        vehicle, sidecar_warnings = read_sidecar(sidecar_path)
        warnings += sidecar_warnings
    elif sidecar is not None:
        raise FileNotFoundError(f"{sidecar_path}: no such sidecar")
    else:
        vehicle = SIMULATOR_VEHICLE
    header, raw = _read_columns(path, set(REQUIRED_COLUMNS + OPTIONAL_COLUMNS))
    missing = [c for c in REQUIRED_COLUMNS if c not in raw]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)} "
                         f"(required: {', '.join(REQUIRED_COLUMNS)}; found: {', '.join(header) or 'none'})")
    line_numbers = np.arange(2, len(raw["t"]) + 2)
    columns = {k: _parse_column(path, k, v, line_numbers) for k, v in raw.items()
               if k in REQUIRED_COLUMNS + OPTIONAL_COLUMNS}
    return recording_from_arrays(columns, vehicle=vehicle, name=path.stem, source=str(path),
                                 line_numbers=line_numbers, warnings=warnings)


def read_sim_log(
    path: str | os.PathLike,
    *,
    steer_column: str = "steering",
    # Defaults: the per-step logs `plm-highway evaluate` writes (rollout.closed_loop.LOG_COLUMNS).
    t_column: str = "t_s",
    speed_column: str = "speed_mps",
    x_column: str = "x_m",
    y_column: str = "y_m",
    heading_column: str = "heading_rad",
    yaw_rate_column: str | None = None,
    lat_accel_column: str | None = None,
    steer_scale: float = 1.0,
    vehicle: VehicleGeometry = SIMULATOR_VEHICLE,
) -> Recording:
    """Map a simulator log (any CSV with a header) onto a :class:`Recording`.

    ``steer_scale`` converts the logged steering command to the front-wheel angle in radians,
    e.g. ``steer_scale=math.pi / 4`` for a normalised action in [-1, 1] with highway-env's default
    ``steering_range``. Other columns of the log are ignored.
    """
    path = Path(path)
    if not (isinstance(steer_scale, (int, float)) and math.isfinite(steer_scale) and steer_scale != 0):
        raise ValueError(f"steer_scale must be a finite, non-zero number (got {steer_scale!r})")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    mapping = {"t": t_column, "steer": steer_column, "speed": speed_column, "x": x_column, "y": y_column,
               "heading": heading_column, "yaw_rate": yaw_rate_column, "lat_accel": lat_accel_column}
    header, raw = _read_columns(path, {col for col in mapping.values() if col is not None})
    missing = [f"'{col}' (for {ours})" for ours, col in mapping.items() if col is not None and col not in raw]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)}; found: {', '.join(header)}")
    line_numbers = np.arange(2, len(raw[t_column]) + 2)
    columns = {ours: _parse_column(path, col, raw[col], line_numbers) for ours, col in mapping.items() if col}
    columns["steer"] = columns["steer"] * steer_scale
    return recording_from_arrays(columns, vehicle=vehicle, name=path.stem, source=str(path),
                                 line_numbers=line_numbers)


# ----------------------------------------------------------------------------------------------
# Writing


def _has_recording_header(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8") as handle:
            first = handle.readline(4096).strip().split(",")
    except (OSError, UnicodeDecodeError):
        return False
    return tuple(first[:len(REQUIRED_COLUMNS)]) == REQUIRED_COLUMNS and set(first[len(REQUIRED_COLUMNS):]) <= set(
        OPTIONAL_COLUMNS)


RECORDING_CSV = file_kind("recording", "a recording CSV", None, _has_recording_header)
RECORDING_SIDECAR = file_kind("recording-sidecar", "a recording sidecar JSON")
RECORDING_TRUTH = file_kind("recording-truth", "a recording's concealed-truth JSON")


def write_recording(recording: Recording, path: str | os.PathLike, write_sidecar: bool | None = None,
                    truth: dict | None = None, overwrite: bool = False) -> Path:
    """Write the CSV, the sidecar (``STEM.json``, unless the car is the simulator's) and, if given, the
    concealed truth (``STEM.truth.json``), published together."""
    path = Path(path)
    names = list(REQUIRED_COLUMNS)
    arrays = [recording.t_s, recording.steer_rad, recording.speed_mps, recording.x_m, recording.y_m,
              np.angle(np.exp(1j * recording.heading_rad))]
    formats = ["%.4f", "%.7f", "%.4f", "%.4f", "%.4f", "%.6f"]
    for name, values, fmt in (("yaw_rate", recording.yaw_rate_radps, "%.6f"),
                              ("lat_accel", recording.lat_accel_mps2, "%.5f")):
        if values is not None:
            names.append(name)
            arrays.append(values)
            formats.append(fmt)
    table = np.column_stack(arrays)
    if write_sidecar is None:
        write_sidecar = recording.vehicle != SIMULATOR_VEHICLE
    outputs = {"csv": (path, RECORDING_CSV)}
    if write_sidecar:
        outputs["sidecar"] = (path.with_suffix(".json"), RECORDING_SIDECAR)
    if truth is not None:
        outputs["truth"] = (path.with_name(path.stem + ".truth.json"), RECORDING_TRUTH)
    with write_outputs(list(outputs.values()), overwrite=overwrite) as staged:
        staged = dict(zip(outputs, staged))
        np.savetxt(staged["csv"], table, delimiter=",", header=",".join(names), comments="", fmt=formats)
        if write_sidecar:
            staged["sidecar"].write_text(json_text(recording.vehicle.sidecar(), RECORDING_SIDECAR, indent=1))
        if truth is not None:
            staged["truth"].write_text(json_text(truth, RECORDING_TRUTH, indent=1))
    return path
