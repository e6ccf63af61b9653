"""A recording checked against itself before any physics is fitted.

A recording describes one motion several times over: the speed and the positions' derivative, the
yaw rate and the heading's derivative, the heading and the direction of travel, the steering and
the way the car turns, the lateral acceleration and speed x yaw rate. Units, signs and time scales
that disagree between these channels are not physics, yet a fit would read them as physics (a
speed in km/h fits as a steering gain of 0.28 with a delay; a time column twice the true scale as
a 0.4 s delay). :func:`check_consistency` measures each relation on the recording's own samples:

======================= ================================ =============================================
check                   measured                         consistent when
======================= ================================ =============================================
``speed_vs_position``   median of speed / |d(x, y)/dt|   within 1/1.25-1.25
``heading_vs_course``   d(course)/dt against d(heading)  same sign; heading - course (median) within
                        /dt (course: direction of         0.35 rad (20 deg; a car slips a few degrees)
                        travel from the positions)
``yaw_rate_vs_heading`` yaw rate against d(heading)/dt    same sign, ratio within 1/1.25-1.25 (at the
                        at the best lag (0-0.6 s)         lag: a late gyro is a sensor, not a unit)
``steer_vs_turning``    the simulator's yaw rate from     the car turns the way the steering says
                        the steering against d(heading)   (best correlation over -0.2 to 1 s of delay
                        /dt                               positive)
``lat_accel_vs_turning`` lateral acceleration against     same sign, ratio within 1/1.25-1.25
                        |d(x, y)/dt| x d(heading)/dt
======================= ================================ =============================================

Derivatives are Savitzky-Golay, over the window the replay uses for the heading (0.5 s) or, on a noisy
recording, over the shortest longer window (:data:`WINDOWS_S`) where the car's turning stands out of the
heading's noise; the gyro, the steering's turn and the lateral acceleration are integrated and put through
the same filter, so every pair compared carries the same smoothing and lag. A turn direction is decided
by a correlation that is strong and, over the independent windows compared, not chance (Fisher's z). A
check that cannot be made says why (a column not recorded, a car that barely turns or barely moves,
turning lost in the heading's noise, channels that do not correlate); :attr:`Consistency.unchecked_turns`
lists the turn checks left undecided, which lower a diagnosis' confidence. When checks fail, :func:`blame` names the channel that is most likely wrong and why:
the same factor on the speed and on the yaw rate is the **time** column's scale (both positions and
heading change that much slower per recorded second); a factor on one of them alone is that
column's **units** (3.6: km/h; 57.3: deg/s; 9.81: g); a turn direction that one channel alone
disagrees with is that channel's **sign** (all others against the heading: the heading's).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from plm_highway.sim2real.record.recording import HEADING_DERIVATIVE_WINDOW_S, Recording
from plm_highway.vehicle.tires import GRAVITY_MPS2

# A ratio between two channels that should agree is consistent within this factor (a wheel-speed
# sensor reads a few per cent off, a filtered gyro a little low; a unit error is 1.6x or more).
RATIO_TOLERANCE = 1.25
# A known unit or scale factor is named when the measured ratio is within this factor of it.
FACTOR_MATCH = 1.06
# The speed's factor and the yaw rate's (or the lateral acceleration's, squared) are the same time
# scale within this factor (the turn rates' ratios carry the noise of a differentiated heading).
TIME_FACTOR_MATCH = 1.15
# The heading may differ from the direction of travel by the slip angle (a few degrees).
MAX_HEADING_COURSE_OFFSET_RAD = 0.35
# A turn direction is decided when the channels correlate at least this well (the wrong sign gives
# -0.9 or so on every recording tried; noise and unmodelled physics stay well above 0.5).
MIN_SIGN_CORRELATION = 0.5
# Turning is seen when the heading's rate varies this much (and many times its noise).
MIN_TURN_RATE_STD_RADPS = 0.01
TURN_NOISE_FACTOR = 5.0
MIN_CHECK_S = 5.0
# Derivative windows tried in turn, shortest first: the first over which the car's turning stands out
# of the heading's noise is used for every turn-rate check (noise through a Savitzky-Golay derivative
# falls as the window's 1.5 power; a lane change's turn rate survives windows of a few seconds).
WINDOWS_S = (HEADING_DERIVATIVE_WINDOW_S, 1.0, 2.0, 4.0, 8.0)
# A turn direction also needs this Fisher z (atanh(rho) x sqrt(independent windows - 3)): a long
# window over a short recording leaves few independent stretches, and few can correlate by chance.
SIGN_Z = 3.0
MAX_GYRO_LAG_S = 0.6
STEER_LAG_S = (-0.2, 1.0)

# Factors by which one channel reads when its unit (or the time scale) is another than the format's.
SPEED_FACTORS = {3.6: "speed in km/h", 2.23694: "speed in mph", 1 / 0.3048: "positions in feet",
                 0.3048: "speed in ft/s"}
YAW_FACTORS = {180 / math.pi: "yaw rate in deg/s", math.pi / 180: "yaw rate in rad/s but read as degrees"}
LAT_FACTORS = {1 / GRAVITY_MPS2: "lateral acceleration in g", GRAVITY_MPS2: "lateral acceleration in m/s^2 / g"}

STATUSES = ("consistent", "contradicts", "not checked")
SIGN_TEXT = {
    "heading": "the heading turns the other way from the other channels (clockwise instead of counter-clockwise?)",
    "yaw_rate": "the gyro turns the other way from the other channels (sign flipped)",
    "steer": "the car turns the other way from the steering (positive must steer left; sign flipped)",
    "lat_accel": "the lateral acceleration points the other way (positive must be to the left)",
    "x, y": "the positions turn the other way from the other channels (a mirrored frame: y down instead of up?)",
}


@dataclass(frozen=True)
class Check:
    """One relation between recorded channels: what was measured and whether it holds."""

    name: str
    channels: tuple[str, ...]
    status: str  # one of STATUSES
    text: str
    ratio: float = math.nan  # the first channel over what the others imply
    correlation: float = math.nan
    lag_s: float = math.nan
    heading_offset_rad: float = math.nan  # heading minus the direction of travel
    seconds: float = 0.0  # of samples compared


@dataclass(frozen=True)
class Contradiction:
    """A channel a recording contradicts itself on, and the likely cause."""

    channel: str  # the recording's column ("t", "speed", "x, y", "heading", "yaw_rate", "steer", "lat_accel")
    cause: str  # "units", "sign", "scale" or "frame"
    text: str


@dataclass(frozen=True)
class Consistency:
    checks: list[Check]
    contradictions: list[Contradiction] = field(default_factory=list)
    window_s: float = HEADING_DERIVATIVE_WINDOW_S  # the derivative window the turn rates were compared over

    @property
    def consistent(self) -> bool:
        return not self.contradictions

    @property
    def not_checked(self) -> list[Check]:
        return [c for c in self.checks if c.status == "not checked"]

    @property
    def unchecked_turns(self) -> list[Check]:
        """The turn checks the recording's own samples could not decide (a column not recorded is not
        among them): a sign or unit error in those channels would go unseen and be fitted as physics."""
        return [c for c in self.not_checked if c.name != "speed_vs_position" and not c.text.startswith("no ")]

    def check(self, name: str) -> Check:
        return next(c for c in self.checks if c.name == name)

    def to_json(self) -> dict:
        return {"consistent": self.consistent, "window_s": self.window_s,
                "contradictions": [asdict(c) for c in self.contradictions],
                "checks": {c.name: {k: v for k, v in asdict(c).items() if k != "name"} for c in self.checks},
                "not_checked": [f"{c.name}: {c.text}" for c in self.not_checked]}

    def summary(self, name: str) -> str:
        lines = [f"Inconsistent: '{name}' contradicts itself, so no physics is fitted: "
                 + "; ".join(f"{c.channel}: {c.text}" for c in self.contradictions) + "."]
        lines.append("Measured: " + "; ".join(c.text for c in self.checks if c.status == "contradicts") + ".")
        if self.not_checked:
            lines.append("Not checked: " + "; ".join(f"{c.name.replace('_', ' ')} ({c.text})"
                                                     for c in self.not_checked) + ".")
        lines.append("Fix the column (units, sign or time scale) and diagnose again.")
        return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Measurements


@dataclass(frozen=True)
class ChannelRates:
    """The recording's own rates, each from one channel (Savitzky-Golay derivatives)."""

    speed_from_position: np.ndarray  # |d(x, y)/dt| [m/s]
    course_rad: np.ndarray  # direction of travel, unwrapped
    course_rate: np.ndarray
    heading_rate: np.ndarray
    valid: np.ndarray  # inside the filter's reach, not in a gap or glitch
    moving: np.ndarray  # valid and moving by the recorded speed and by the positions
    heading_rate_noise: float
    window_s: float = HEADING_DERIVATIVE_WINDOW_S

    def through_filter(self, rate: np.ndarray, dt: float) -> np.ndarray:
        """A rate channel (the gyro's, the steering's) as the heading's rate sees it: integrated to an
        angle, then differentiated by the same filter, so both carry the same smoothing and lag."""
        angle = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt)])
        return _derivative(angle, self.window_s, dt)


def _window(window_s: float, dt: float) -> int:
    return max(5, round(window_s / dt) | 1)


def _derivative(values: np.ndarray, window_s: float, dt: float) -> np.ndarray:
    window = min(_window(window_s, dt), (values.shape[0] - 1) | 1 if values.shape[0] % 2 == 0 else values.shape[0])
    return savgol_filter(values, window, 2, deriv=1, delta=dt, mode="interp")


def channel_rates(rec: Recording, window_s: float = HEADING_DERIVATIVE_WINDOW_S) -> ChannelRates:
    """The rates, each a Savitzky-Golay derivative over ``window_s`` (longer windows for noisier recordings)."""
    dt = rec.dt_s
    window = _window(window_s, dt)
    half = window // 2

    def rate(values: np.ndarray) -> np.ndarray:
        return savgol_filter(values, window, 2, deriv=1, delta=dt, mode="interp")

    x_rate, y_rate, heading_rate = rate(rec.x_m), rate(rec.y_m), rate(rec.heading_rad)
    speed_pos = np.hypot(x_rate, y_rate)
    bad = ~(rec.usable if rec.usable is not None else np.ones(rec.n, bool))
    valid = np.convolve(bad.astype(float), np.ones(2 * half + 1), mode="same") == 0
    valid[:half + 1] = False
    valid[-half - 1:] = False
    floor = rec.speed_floor_mps
    moving = valid & (rec.speed_mps > floor) & (speed_pos > floor)
    course = np.unwrap(np.arctan2(y_rate, x_rate))
    course_rate = np.gradient(course, dt)
    # The heading's white noise through the derivative filter (third differences, robust).
    d3 = np.diff(rec.heading_rad, 3)
    sigma = 1.4826 * float(np.median(np.abs(d3 - np.median(d3)))) / math.sqrt(20.0) if d3.size else 0.0
    taps = savgol_filter(np.eye(window)[half], window, 2, deriv=1, delta=dt)  # impulse response
    return ChannelRates(speed_pos, course, course_rate, heading_rate, valid, moving,
                        sigma * float(np.sqrt(np.sum(taps**2))), window_s)


def _slope(y: np.ndarray, x: np.ndarray) -> float:
    """Least-squares ratio y / x through the origin."""
    denominator = float(np.dot(x, x))
    return float(np.dot(x, y) / denominator) if denominator > 0 else math.nan


def _lagged_fit(a: np.ndarray, b: np.ndarray, mask: np.ndarray, lags: range, dt: float
                ) -> tuple[float, float, float]:
    """(lag [s], correlation, slope a/b) at the lag where a(t + lag) correlates best with b(t) in magnitude."""
    idx = np.flatnonzero(mask)
    best = (0.0, 0.0, math.nan)
    for lag in lags:
        i = idx[(idx + lag >= 0) & (idx + lag < a.shape[0])]
        if i.size < 10:
            continue
        u, v = a[i + lag], b[i]
        if np.std(u) == 0 or np.std(v) == 0:
            continue
        rho = float(np.corrcoef(u, v)[0, 1])
        if abs(rho) > abs(best[1]):
            best = (lag * dt, rho, _slope(u, v))
    return best


def _factor_name(ratio: float, table: dict[float, str]) -> str | None:
    for factor, name in table.items():
        if abs(math.log(abs(ratio) / factor)) < math.log(FACTOR_MATCH):
            return name
    return None


def _within(ratio: float) -> bool:
    return math.isfinite(ratio) and ratio > 0 and abs(math.log(ratio)) <= math.log(RATIO_TOLERANCE)


def _seconds(mask: np.ndarray, dt: float) -> float:
    return float(mask.sum()) * dt


def _turning(rec: Recording, d: ChannelRates) -> tuple[np.ndarray, bool, float]:
    """(the samples compared, whether the car turns well above the heading rate's noise, the rate's std)."""
    turning = d.moving & d.valid
    turn_std = float(np.std(d.heading_rate[turning])) if turning.any() else 0.0
    turns = (_seconds(turning, rec.dt_s) >= MIN_CHECK_S and turn_std >= MIN_TURN_RATE_STD_RADPS
             and turn_std >= TURN_NOISE_FACTOR * d.heading_rate_noise)
    return turning, turns, turn_std


def _decided(rho: float, seconds: float, window_s: float) -> bool:
    """Whether a correlation decides a turn direction: strong, and unlikely by chance given the number
    of independent stretches compared (one per filter window; Fisher's z at least SIGN_Z)."""
    if not math.isfinite(rho) or abs(rho) < MIN_SIGN_CORRELATION:
        return False
    independent = seconds / max(window_s, HEADING_DERIVATIVE_WINDOW_S)
    return independent > 3 and abs(math.atanh(min(abs(rho), 0.999999))) * math.sqrt(independent - 3) >= SIGN_Z


def check_consistency(rec: Recording) -> Consistency:
    """Every relation between the recording's channels that its columns allow (see the module docstring)."""
    dt = rec.dt_s
    checks: list[Check] = []
    # The shortest derivative window over which the car's turning stands out of the heading's noise:
    # a noisy recording is compared over longer windows (every rate through the same filter).
    longest_noise = math.nan  # the heading rate's noise over the longest window, when none shows turning
    for window_s in WINDOWS_S:
        d = channel_rates(rec, window_s)
        turning, turns, turn_std = _turning(rec, d)
        if turns:
            break
    if not turns:
        longest_noise = d.heading_rate_noise
        d = channel_rates(rec)
        turning, _, turn_std = _turning(rec, d)
    window_s = d.window_s
    over = f" over {window_s:g}-s windows" if window_s != HEADING_DERIVATIVE_WINDOW_S else ""

    # Speed against the positions.
    moving_s = _seconds(d.moving, dt)
    still = d.valid & (rec.speed_mps > rec.speed_floor_mps) & (d.speed_from_position <= rec.speed_floor_mps)
    if _seconds(still, dt) >= MIN_CHECK_S and _seconds(still, dt) > moving_s:
        checks.append(Check("speed_vs_position", ("speed", "x, y"), "contradicts",
                            f"the positions stand still while the speed column says "
                            f"{float(np.median(rec.speed_mps[still])):.3g} m/s for {_seconds(still, dt):.0f} s",
                            ratio=math.inf, seconds=_seconds(still, dt)))
    elif moving_s < MIN_CHECK_S:
        checks.append(Check("speed_vs_position", ("speed", "x, y"), "not checked",
                            f"the car moves for only {moving_s:.1f} s", seconds=moving_s))
    else:
        ratio = float(np.median(rec.speed_mps[d.moving] / d.speed_from_position[d.moving]))
        ok = _within(ratio)
        checks.append(Check("speed_vs_position", ("speed", "x, y"), "consistent" if ok else "contradicts",
                            f"speed is {ratio:.3g} x the positions' derivative", ratio=ratio, seconds=moving_s))

    if _seconds(turning, dt) < MIN_CHECK_S:
        no_turns = f"the car moves for only {_seconds(turning, dt):.1f} s"
    elif turn_std < MIN_TURN_RATE_STD_RADPS:
        no_turns = f"the car barely turns (heading rate std {turn_std:.3g} rad/s)"
    else:
        no_turns = (f"the turning does not stand out of the heading's noise even over {WINDOWS_S[-1]:g}-s windows "
                    f"(heading rate std {turn_std:.3g} rad/s; its noise {longest_noise:.3g} rad/s over "
                    f"{WINDOWS_S[-1]:g} s)")
    turning_s = _seconds(turning, dt)

    # The heading against the direction of travel.
    if turns:
        mean_direction = np.mean(np.exp(1j * (rec.heading_rad - d.course_rad)[turning]))
        offset = float(np.angle(mean_direction))
        rho = float(np.corrcoef(d.course_rate[turning], d.heading_rate[turning])[0, 1])
        ratio = _slope(d.course_rate[turning], d.heading_rate[turning])
        # Rotated frames keep heading - course steady at the rotation; mirrored ones make it wander.
        rotated = abs(mean_direction) >= 0.9 and abs(offset) > MAX_HEADING_COURSE_OFFSET_RAD
        decided = _decided(rho, turning_s, window_s)
        status = ("contradicts" if rho < 0 or rotated else "consistent") if decided else "not checked"
        text = (f"the direction of travel turns {ratio:+.3g} x the heading's rate (rho = {rho:+.2f}{over}) and "
                f"differs from the heading by {math.degrees(offset):+.1f} deg")
        checks.append(Check("heading_vs_course", ("heading", "x, y"), status, text, ratio=ratio, correlation=rho,
                            heading_offset_rad=offset, seconds=_seconds(turning, dt)))
    else:
        checks.append(Check("heading_vs_course", ("heading", "x, y"), "not checked", no_turns))

    # The gyro against the heading.
    if rec.yaw_rate_radps is None:
        checks.append(Check("yaw_rate_vs_heading", ("yaw_rate", "heading"), "not checked", "no yaw_rate column"))
    elif not turns:
        checks.append(Check("yaw_rate_vs_heading", ("yaw_rate", "heading"), "not checked", no_turns))
    else:
        max_lag = round(MAX_GYRO_LAG_S / dt)
        gyro = d.through_filter(rec.yaw_rate_radps, dt)
        lag, rho, ratio = _lagged_fit(gyro, d.heading_rate, turning, range(-max_lag, max_lag + 1), dt)
        decided = _decided(rho, turning_s, window_s)
        status = ("consistent" if rho > 0 and _within(ratio) else "contradicts") if decided else "not checked"
        text = (f"yaw_rate is {ratio:+.3g} x the heading's rate (rho = {rho:+.2f} at a lag of {lag:+.2f} s{over})"
                if status != "not checked" else
                f"yaw_rate and the heading's rate barely correlate (rho = {rho:+.2f})")
        checks.append(Check("yaw_rate_vs_heading", ("yaw_rate", "heading"), status, text, ratio=ratio,
                            correlation=rho, lag_s=lag, seconds=_seconds(turning, dt)))

    # The steering against the way the car turns (the simulator's own geometry).
    if turns:
        v = rec.vehicle
        kinematic = rec.speed_mps * np.sin(np.arctan(v.cg_to_rear_m / v.wheelbase_m * np.tan(rec.steer_rad))) \
            / v.cg_to_rear_m
        lo, hi = (round(s / dt) for s in STEER_LAG_S)
        # d(heading)(t) against the steering's turn at t - lag: a(t + lag) ~ b(t) with a = heading rate.
        lag, rho, ratio = _lagged_fit(d.heading_rate, d.through_filter(kinematic, dt), turning, range(lo, hi + 1), dt)
        decided = _decided(rho, turning_s, window_s)
        status = ("consistent" if rho > 0 else "contradicts") if decided else "not checked"
        text = (f"the car turns {ratio:+.3g} x the way the steering says (rho = {rho:+.2f} at a delay of {lag:.2f} s"
                f"{over})"
                if decided else f"the steering and the turning barely correlate (rho = {rho:+.2f})")
        checks.append(Check("steer_vs_turning", ("steer", "heading"), status, text, ratio=ratio, correlation=rho,
                            lag_s=lag, seconds=_seconds(turning, dt)))
    else:
        checks.append(Check("steer_vs_turning", ("steer", "heading"), "not checked", no_turns))

    # The lateral accelerometer against speed x turn rate.
    if rec.lat_accel_mps2 is None:
        checks.append(Check("lat_accel_vs_turning", ("lat_accel", "speed", "heading"), "not checked",
                            "no lat_accel column"))
    elif not turns:
        checks.append(Check("lat_accel_vs_turning", ("lat_accel", "speed", "heading"), "not checked", no_turns))
    else:
        expected = d.speed_from_position * d.heading_rate  # the path's own: speed units cannot enter
        lat = d.through_filter(rec.lat_accel_mps2, dt)
        rho = float(np.corrcoef(lat[turning], expected[turning])[0, 1])
        ratio = _slope(lat[turning], expected[turning])
        decided = _decided(rho, turning_s, window_s)
        status = ("consistent" if rho > 0 and _within(ratio) else "contradicts") if decided else "not checked"
        text = (f"lat_accel is {ratio:+.3g} x the positions' speed x the heading's rate (rho = {rho:+.2f}{over})"
                if decided else f"lat_accel and the path's acceleration barely correlate (rho = {rho:+.2f})")
        checks.append(Check("lat_accel_vs_turning", ("lat_accel", "speed", "heading"), status, text, ratio=ratio,
                            correlation=rho, seconds=_seconds(turning, dt)))
    consistency = Consistency(checks, window_s=window_s)
    return Consistency(checks, blame(consistency), window_s)


# ----------------------------------------------------------------------------------------------
# Which channel is wrong


def blame(consistency: Consistency) -> list[Contradiction]:
    """The channels most likely wrong, and why (see the module docstring); empty when every check holds."""
    by_name = {c.name: c for c in consistency.checks}
    if not any(c.status == "contradicts" for c in consistency.checks):
        return []
    out: list[Contradiction] = []
    speed, yaw, lat = by_name["speed_vs_position"], by_name["yaw_rate_vs_heading"], by_name["lat_accel_vs_turning"]
    heading, steer = by_name["heading_vs_course"], by_name["steer_vs_turning"]

    # Turn direction: every decided channel says whether it turns the heading's way. The smaller camp
    # is blamed (the heading counts in its own camp); equal camps cannot be told apart.
    votes = {}
    if heading.status != "not checked" and abs(heading.correlation) >= MIN_SIGN_CORRELATION:
        votes["x, y"] = heading.correlation > 0
    for check, channel in ((yaw, "yaw_rate"), (steer, "steer"), (lat, "lat_accel")):
        if check.status != "not checked":
            votes[channel] = check.correlation > 0
    against = [c for c, agrees in votes.items() if not agrees]
    with_heading = ["heading"] + [c for c, agrees in votes.items() if agrees]
    if against:
        if len(against) < len(with_heading):
            out += [Contradiction(c, "frame" if c == "x, y" else "sign", SIGN_TEXT[c]) for c in against]
        elif len(against) > len(with_heading):
            out += [Contradiction(c, "frame" if c == "x, y" else "sign", SIGN_TEXT[c]) for c in with_heading]
        else:
            out.append(Contradiction(" or ".join(with_heading + against), "sign",
                                     f"{', '.join(with_heading)} and {', '.join(against)} turn opposite ways; the "
                                     "recording does not say which is flipped"))

    # Scale: the same factor on the speed (against positions) and on the yaw rate (against the heading)
    # is the time column; one alone is that channel's units.
    time_factor = None
    yaw_ratio = abs(yaw.ratio) if yaw.status != "not checked" else math.nan
    lat_ratio = abs(lat.ratio) if lat.status != "not checked" else math.nan
    if speed.status == "contradicts" and math.isfinite(speed.ratio):
        if math.isfinite(yaw_ratio) and abs(math.log(yaw_ratio / speed.ratio)) < math.log(TIME_FACTOR_MATCH):
            time_factor = speed.ratio
        elif math.isfinite(lat_ratio) and abs(math.log(lat_ratio / speed.ratio**2)) < math.log(TIME_FACTOR_MATCH):
            time_factor = speed.ratio  # the path's acceleration is two derivatives in time
    if time_factor is not None:
        out.append(Contradiction("t", "scale", _time_text(time_factor)))
    else:
        if speed.status == "contradicts":
            if not math.isfinite(speed.ratio):
                out.append(Contradiction("x, y", "units", speed.text + " (positions not recorded or frozen?)"))
            else:
                name = _factor_name(speed.ratio, SPEED_FACTORS)
                if math.isfinite(yaw_ratio) or math.isfinite(lat_ratio):  # the time scale is ruled out
                    out.append(Contradiction("speed", "units" if name else "scale",
                                             f"{speed.text}: {name or 'a scale error'}"))
                else:  # nothing else measures the time scale
                    out.append(Contradiction("speed" if name else "t or speed", "units" if name else "scale",
                                             f"{speed.text}: {name + ', or ' if name else ''}"
                                             f"{_time_text(speed.ratio)[0].lower() + _time_text(speed.ratio)[1:]}"
                                             f" (no yaw_rate or lat_accel column to tell them apart)"))
        if math.isfinite(yaw_ratio) and not _within(yaw_ratio):
            name = _factor_name(yaw_ratio, YAW_FACTORS)
            out.append(Contradiction("yaw_rate", "units" if name else "scale",
                                     f"yaw_rate is {yaw_ratio:.3g} x the heading's rate: {name or 'a scale error'}"))
        if math.isfinite(lat_ratio) and not _within(lat_ratio):
            name = _factor_name(lat_ratio, LAT_FACTORS)
            out.append(Contradiction("lat_accel", "units" if name else "scale",
                                     f"lat_accel is {lat_ratio:.3g} x the path's acceleration: "
                                     f"{name or 'a scale error'}"))
    if heading.status == "contradicts" and heading.correlation > 0:
        out.append(Contradiction("heading", "frame", f"the heading differs from the direction of travel by "
                                 f"{math.degrees(heading.heading_offset_rad):+.0f} deg (measured from another axis, e.g. "
                                 "north, or the car's rear?)"))
    if not out:  # a check failed in a way none of the above names
        out += [Contradiction(" and ".join(c.channels), "scale", c.text) for c in consistency.checks
                if c.status == "contradicts"]
    return out


def _time_text(factor: float) -> str:
    return (f"Time column scale: positions, heading and speed agree only if the recorded time is {factor:.3g} x "
            f"the true time (speed and yaw rate say the car moves {factor:.3g} x as far per recorded second as "
            "the positions and heading show)")
