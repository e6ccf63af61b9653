"""A recording checked against itself before any physics is fitted: every self-contradiction class is
"inconsistent" with the channel and the likely cause named, consistent recordings never are; and the
CSV reader's bounds (bytes, columns, line length) and its memory with many ignored columns."""

from __future__ import annotations

import json
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plm_highway.cli import main
from plm_highway.sim2real.benchmark import CASE_SETS
from plm_highway.sim2real.diagnose import diagnose
from plm_highway.sim2real.physics.synth import NoiseLevels, as_read, make_recording
from plm_highway.sim2real.record import recording as recording_module
from plm_highway.sim2real.record.consistency import check_consistency
from plm_highway.sim2real.record.recording import read_recording, recording_from_arrays, write_recording
from plm_highway.sim2real.rendering import to_json

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "iac_putnam_run4_2.csv"


def _base(noise_scale: float):
    recording, _ = make_recording({"transport_delay": 0.15, "tire_slip": None}, rng=np.random.default_rng(31),
                                  duration_s=60.0, noise=NoiseLevels().scaled(noise_scale))
    return recording


@pytest.fixture(scope="session")
def base():
    """A consistent 60-s recording with every optional channel (a late car, the seed paper's tires)."""
    return _base(1.0)


# The same drive measured 5 and 10 times as noisily: over the default 0.5-s derivative window the
# heading's rate is then mostly noise (the turn checks must look over longer windows).
NOISE_SCALES = (5.0, 10.0)


@pytest.fixture(scope="session", params=NOISE_SCALES, ids=lambda s: f"noise x{s:g}")
def noisy_base(request):
    return _base(request.param)


def _corrupted(recording, change, drop=()):
    columns = {k: v.copy() for k, v in recording.columns().items() if k not in drop}
    change(columns)
    columns["heading"] = np.angle(np.exp(1j * columns["heading"]))  # as a file holds it
    return recording_from_arrays(columns, vehicle=recording.vehicle, name="corrupted")


def _scale(key, factor):
    def change(c):
        c[key] = c[key] * factor
    return change


def _set(key, fn):
    def change(c):
        c[key] = fn(c)
    return change


def _freeze_positions(c):
    c["x"][:] = c["x"][0]
    c["y"][:] = c["y"][0]


# (change, columns dropped, the channel named, the cause, words the explanation holds)
CLASSES = {
    "speed in km/h": (_scale("speed", 3.6), (), "speed", "units", "km/h"),
    "speed in mph": (_scale("speed", 2.23694), (), "speed", "units", "mph"),
    "time column doubled": (_scale("t", 2.0), (), "t", "scale", "2 x the true time"),
    "time column halved": (_scale("t", 0.5), (), "t", "scale", "the recorded time is 0.5"),
    "steering sign flipped": (_scale("steer", -1.0), (), "steer", "sign", "positive must steer left"),
    "yaw rate sign flipped": (_scale("yaw_rate", -1.0), (), "yaw_rate", "sign", "sign flipped"),
    "yaw rate in deg/s": (_set("yaw_rate", lambda c: np.degrees(c["yaw_rate"])), (), "yaw_rate", "units", "deg/s"),
    "heading clockwise": (_scale("heading", -1.0), (), "heading", "sign", "clockwise"),
    "heading from north": (_set("heading", lambda c: c["heading"] - math.pi / 2), (), "heading", "frame", "-90 deg"),
    "y axis down": (_scale("y", -1.0), (), "x, y", "frame", "mirrored"),
    "lateral acceleration in g": (_scale("lat_accel", 1 / 9.80665), (), "lat_accel", "units", " in g"),
    "lateral acceleration sign flipped": (_scale("lat_accel", -1.0), (), "lat_accel", "sign", "to the left"),
    "positions frozen": (_freeze_positions, (), "x, y", "units", "stand still"),
    "speed in km/h, no gyro": (_scale("speed", 3.6), ("yaw_rate", "lat_accel"), "speed", "units", "km/h"),
    "time doubled, no gyro": (_scale("t", 2.0), ("yaw_rate", "lat_accel"), "t or speed", "scale", "2 x the true"),
    "steering sign flipped, no gyro": (_scale("steer", -1.0), ("yaw_rate", "lat_accel"), "steer", "sign", "flipped"),
}


@pytest.mark.parametrize("name", list(CLASSES))
def test_each_self_contradiction_is_inconsistent_naming_the_channel_and_the_cause(base, name):
    change, drop, channel, cause, words = CLASSES[name]
    recording = _corrupted(base, change, drop)
    result = to_json(diagnose(recording))
    assert result["verdict"] == "inconsistent", result["summary"]
    assert result["effects"] == [] and "fit" not in result  # no physics
    blamed = [(c["channel"], c["cause"]) for c in result["consistency"]["contradictions"]]
    assert blamed == [(channel, cause)], (blamed, result["summary"])
    assert words in result["consistency"]["contradictions"][0]["text"]
    assert result["summary"].startswith("Inconsistent:") and channel in result["summary"]


@pytest.mark.parametrize("name", list(CLASSES))
def test_each_self_contradiction_is_found_on_a_noisy_recording_too(noisy_base, name):
    """A sign or unit error is never fitted as physics because the recording is noisy."""
    change, drop, channel, cause, words = CLASSES[name]
    result = to_json(diagnose(_corrupted(noisy_base, change, drop)))
    assert result["verdict"] == "inconsistent", result["summary"]
    assert result["effects"] == []
    blamed = [(c["channel"], c["cause"]) for c in result["consistency"]["contradictions"]]
    assert blamed == [(channel, cause)], (blamed, result["summary"])
    assert words in result["consistency"]["contradictions"][0]["text"]


@pytest.fixture(scope="module")
def very_noisy_base():
    """20 times the default noise: the heading's step noise (0.057 rad) is a quarter of a glitch's size."""
    return _base(20.0)


@pytest.mark.parametrize("name", list(CLASSES))
def test_a_very_noisy_recordings_self_contradiction_blames_its_channel(very_noisy_base, name):
    """The heading's noise is not mistaken for glitches (which would leave nothing to check) when a gyro in the
    wrong units or sign cannot serve as their reference: the contradiction is still found and blamed."""
    change, drop, channel, cause, _ = CLASSES[name]
    consistency = check_consistency(_corrupted(very_noisy_base, change, drop))
    assert not consistency.consistent
    assert [(c.channel, c.cause) for c in consistency.contradictions] == [(channel, cause)]


def test_a_very_noisy_consistent_recording_is_consistent(very_noisy_base):
    assert check_consistency(very_noisy_base).consistent


def test_a_heading_glitch_is_found_in_a_very_noisy_recording_with_or_without_a_gyro(very_noisy_base):
    for drop, gyro in ((), "yaw_rate"), (("yaw_rate", "lat_accel"), "faster than"):
        columns = {k: v.copy() for k, v in very_noisy_base.columns().items() if k not in drop}
        columns["heading"][1500:] += 1.0  # a localisation jump of 1 rad at t = 30 s
        recording = recording_from_arrays(columns, vehicle=very_noisy_base.vehicle, name="glitch")
        assert not recording.usable[1500] and recording.usable.mean() > 0.9, drop
        assert any("heading jumps by +1." in w and gyro in w for w in recording.warnings), recording.warnings


def test_a_noisy_consistent_recording_is_checked_not_skipped(noisy_base):
    """Every check is made (over a longer window than the clean recording's) and every one holds."""
    checks = check_consistency(noisy_base)
    assert {c.name: c.status for c in checks.checks} == {name: "consistent" for name in (
        "speed_vs_position", "heading_vs_course", "yaw_rate_vs_heading", "steer_vs_turning", "lat_accel_vs_turning")}
    assert checks.window_s > check_consistency(_base(1.0)).window_s
    yaw = checks.check("yaw_rate_vs_heading")
    assert yaw.ratio == pytest.approx(1.0, abs=0.1) and yaw.correlation > 0.9
    assert checks.check("steer_vs_turning").correlation > 0.9


def test_a_noisy_consistent_recording_gets_physics_at_normal_confidence(noisy_base):
    result = to_json(diagnose(noisy_base))
    assert result["verdict"] not in ("inconsistent",), result["summary"]
    assert result["consistency"]["consistent"] is True and result["consistency"]["not_checked"] == []
    assert result["confidence"] == "normal", result["summary"]


def test_turn_checks_that_cannot_be_made_lower_the_confidence_and_are_named():
    """A heading so noisy that no window shows the turning: the steering's sign is unchecked, said so."""
    recording, _ = make_recording({"transport_delay": 0.15, "tire_slip": None}, rng=np.random.default_rng(31),
                                  duration_s=60.0, noise=NoiseLevels(heading_rad=0.5), with_yaw_rate=False)
    checks = check_consistency(recording)
    assert checks.consistent
    assert checks.check("steer_vs_turning").status == "not checked"
    assert "does not stand out of the heading's noise" in checks.check("steer_vs_turning").text
    result = to_json(diagnose(recording))
    assert result["confidence"] == "low"
    assert "could not be checked against itself for" in result["summary"] and "steer vs turning" in result["summary"]
    # A column not recorded is no such doubt: the same drive with a quiet heading is normal confidence.
    quiet = to_json(diagnose(_base(1.0)))
    assert quiet["confidence"] == "normal"


def test_what_could_not_be_checked_is_said(base):
    recording = _corrupted(base, _scale("speed", 3.6), ("yaw_rate", "lat_accel"))
    result = to_json(diagnose(recording))
    not_checked = result["consistency"]["not_checked"]
    assert any(item.startswith("yaw_rate_vs_heading: no yaw_rate column") for item in not_checked)
    assert any(item.startswith("lat_accel_vs_turning: no lat_accel column") for item in not_checked)
    assert "Not checked:" in result["summary"]
    # A car driving straight cannot show which way it turns: said, not guessed.
    straight = recording_from_arrays({"t": base.t_s, "steer": np.zeros(base.n), "speed": np.full(base.n, 20.0),
                                      "x": 20.0 * base.t_s, "y": np.zeros(base.n), "heading": np.zeros(base.n)})
    checks = check_consistency(straight)
    assert checks.consistent
    assert checks.check("steer_vs_turning").status == "not checked"
    assert "barely turns" in checks.check("steer_vs_turning").text


def _library_recordings():
    for set_name, cases in CASE_SETS.items():
        for case in cases:
            yield f"{set_name}:{case.name}", case.effects, case.options
    yield "no gyro", {"transport_delay": 0.3}, {"with_yaw_rate": False, "with_lat_accel": False}
    yield "steering gain 0.3", {"steering_gain": 0.3}, {}
    yield "delay 0.6 s", {"transport_delay": 0.6}, {}
    yield "late gyro 0.5 s", {"sensor_delay": 0.5}, {}
    yield "simulator", {}, {"model": "simulator"}
    yield "5 Hz", {"actuator_lag": 0.2}, {"sample_hz": 5.0}


@pytest.mark.parametrize("case", list(_library_recordings()), ids=lambda c: c[0])
def test_consistent_recordings_are_not_flagged(case):
    _, effects, options = case
    recording, _ = make_recording(effects, rng=np.random.default_rng(2), **({"duration_s": 60.0} | options))
    checks = check_consistency(as_read(recording))
    assert checks.consistent, [c.text for c in checks.contradictions]
    assert checks.check("speed_vs_position").status == "consistent"


@pytest.mark.parametrize("case", list(_library_recordings()), ids=lambda c: c[0])
def test_noisy_consistent_recordings_are_not_flagged_and_are_checked(case):
    """No false alarm five times as noisy, and no turn check skipped for the noise."""
    _, effects, options = case
    recording, _ = make_recording(effects, rng=np.random.default_rng(2), noise=NoiseLevels().scaled(5.0),
                                  **({"duration_s": 60.0} | options))
    checks = check_consistency(as_read(recording))
    assert checks.consistent, [c.text for c in checks.contradictions]
    assert [c.name for c in checks.not_checked if not c.text.startswith("no ")] == []


@pytest.mark.skipif(not REAL.is_file(), reason="../shared/real is absent")
def test_the_real_recording_is_consistent():
    checks = check_consistency(read_recording(REAL))
    assert checks.consistent
    statuses = {c.name: c.status for c in checks.checks}
    assert statuses == {"speed_vs_position": "consistent", "heading_vs_course": "consistent",
                        "yaw_rate_vs_heading": "consistent", "steer_vs_turning": "consistent",
                        "lat_accel_vs_turning": "not checked"}
    assert 0.2 < checks.check("yaw_rate_vs_heading").lag_s < 0.5  # the late gyro: a sensor, not a unit


@settings(max_examples=12, deadline=None)
@given(factor=st.one_of(st.floats(0.9, 1.1), st.floats(1.5, 20.0), st.floats(0.05, 0.65)))
def test_a_speed_scale_is_flagged_exactly_when_it_leaves_the_tolerance(base, factor):
    checks = check_consistency(_corrupted(base, _scale("speed", factor)))
    speed = checks.check("speed_vs_position")
    assert speed.ratio == pytest.approx(factor, rel=0.02)
    assert checks.consistent == (0.9 <= factor <= 1.1)
    if not checks.consistent:
        assert [c.channel for c in checks.contradictions] == ["speed"]


def test_the_cli_reports_inconsistent_with_exit_0_and_a_consistency_figure(base, tmp_path, capsys):
    recording = _corrupted(base, _scale("speed", 3.6))
    path = write_recording(recording, tmp_path / "kmh.csv")
    out, report = tmp_path / "d.json", tmp_path / "report"
    assert main(["sim2real", "diagnose", str(path), "--json", str(out), "--report", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "Inconsistent:" in printed and "km/h" in printed and "verdict: inconsistent" in printed
    data = json.loads(out.read_text())
    assert data["verdict"] == "inconsistent" and data["consistency"]["contradictions"][0]["channel"] == "speed"
    assert sorted(p.name for p in report.iterdir()) == [".plm-highway-output.json", "consistency.png",
                                                        "diagnosis.json", "summary.md"]


def test_a_consistent_diagnosis_carries_its_checks(base):
    result = to_json(diagnose(base))
    assert result["verdict"] == "mismatch"
    assert result["consistency"]["consistent"] is True
    assert all(c["status"] == "consistent" for c in result["consistency"]["checks"].values())


# ----------------------------------------------------------------------------------------------
# The reader's bounds


def _write_wide(path: Path, recording, ignored: int) -> int:
    columns = recording.columns()
    columns["heading"] = np.angle(np.exp(1j * columns["heading"]))
    junk = np.random.default_rng(0).uniform(-1e3, 1e3, (recording.n, ignored))
    table = np.column_stack([columns[k] for k in columns] + [junk])
    header = ",".join(list(columns) + [f"extra_{i}" for i in range(ignored)])
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt="%.6f")
    return path.stat().st_size


def test_only_the_needed_columns_are_stored(base, tmp_path):
    """A file mostly of ignored columns costs memory for the recording's columns only."""
    size = _write_wide(tmp_path / "wide.csv", base, ignored=150)
    tracemalloc.start()
    try:
        recording = read_recording(tmp_path / "wide.csv")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert recording.n == base.n
    np.testing.assert_allclose(recording.steer_rad, base.steer_rad, atol=1e-6)
    # Stored as Python strings, all 158 columns take several times the file's size; 8 of them a fraction.
    assert peak < 0.5 * size, (peak, size)


@pytest.mark.parametrize("limit, value, words", [
    ("MAX_BYTES", 10_000, "bytes; at most 10,000 are accepted"),
    ("MAX_COLUMNS", 20, "30 columns in the header; at most 20 are accepted"),
    ("MAX_LINE_CHARS", 200, "longer than 200 characters"),
])
def test_files_over_a_limit_are_refused_naming_file_and_limit(base, tmp_path, capsys, monkeypatch, limit, value,
                                                             words):
    path = tmp_path / "big.csv"
    _write_wide(path, base.slice(0, 1000), ignored=22)
    monkeypatch.setattr(recording_module, limit, value)
    assert main(["sim2real", "diagnose", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and str(path) in err and words in err, err
    assert "Traceback" not in err


def test_an_oversized_sidecar_is_refused(base, tmp_path, capsys):
    path = write_recording(base, tmp_path / "r.csv")
    (tmp_path / "r.json").write_text('{"wheelbase_m": 2.8, "notes": "' + "x" * 70_000 + '"}')
    assert main(["sim2real", "diagnose", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "r.json" in err and "at most 65,536" in err, err
