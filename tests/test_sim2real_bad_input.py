"""sim2real on bad or uninformative input: refused with exit code 2 and a message naming the culprit,
or an explicit verdict (unexcited, unexplained), never a "match"; strict JSON; no warnings from
NumPy. Table-driven: a case is one line."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from plm_highway.cli import main
from plm_highway.sim2real.diagnose import diagnose, steering_frequency_hz
from plm_highway.sim2real.fit.fitting import fit_candidate
from plm_highway.sim2real.fit.problem import make_problem
from plm_highway.sim2real.fit.selection import Selection
from plm_highway.sim2real.physics.synth import make_recording
from plm_highway.sim2real.record import recording as recording_module
from plm_highway.sim2real.record.recording import read_recording, write_recording
from plm_highway.sim2real.rendering import runner_up_text, to_json


@pytest.fixture(scope="module")
def base_recording():
    recording, _ = make_recording({"transport_delay": 0.15}, rng=np.random.default_rng(4), duration_s=40.0)
    return recording


def _csv(tmp_path, recording, name="rec.csv", **overrides):
    columns = recording.columns() | overrides
    names = list(columns)
    path = tmp_path / name
    np.savetxt(path, np.column_stack([columns[k] for k in names]), delimiter=",", header=",".join(names),
               comments="", fmt="%.9g")
    return path


def _run(*argv) -> int:
    return main(["sim2real", *argv])


# (case id, how to make the input, extra CLI arguments, text the error must contain)
REFUSED = [
    ("zero-speed", lambda r: {"speed": np.zeros(r.n)}, [], "too little usable data"),
    ("block-s-too-long", None, ["--block-s", "500"], "--block-s 500 s is too long"),
    ("block-s-nan", None, ["--block-s", "nan"], "argument --block-s: nan is outside the accepted range"),
    ("anchor-s-nan", None, ["--anchor-s", "nan"], "argument --anchor-s: nan is outside the accepted range"),
    ("anchor-s-tiny", None, ["--anchor-s", "1e-9"], "--anchor-s must be between"),
    ("steer-scale-without-log", None, ["--steer-scale", "0.2"], "--steer-scale applies to simulator logs"),
]


@pytest.mark.parametrize("case, mutate, extra, message", REFUSED, ids=[c[0] for c in REFUSED])
def test_unusable_recordings_and_options_are_refused_naming_the_culprit(tmp_path, capsys, base_recording, case,
                                                                         mutate, extra, message):
    path = _csv(tmp_path, base_recording, **(mutate(base_recording) if mutate else {}))
    out = tmp_path / "out.json"
    assert _run("diagnose", str(path), "--json", str(out), "--quiet", *extra) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err and not out.exists()


def test_zero_speed_is_refused_with_the_numbers(tmp_path, capsys, base_recording):
    path = _csv(tmp_path, base_recording, speed=np.zeros(base_recording.n))
    assert _run("diagnose", str(path), "--quiet") == 2
    err = capsys.readouterr().err
    assert "0.0 s (0%) of the 40.0 s recording are scored" in err and "top speed is 0 m/s" in err


@pytest.mark.parametrize("scale", ["0", "nan", "inf", "-inf"])
def test_a_nonsense_steer_scale_is_blamed_on_the_option(tmp_path, capsys, base_recording, scale):
    columns = base_recording.columns()
    log = tmp_path / "log.csv"
    names = {"t": "t_s", "steer": "steering", "speed": "speed_mps", "x": "x_m", "y": "y_m", "heading": "heading_rad"}
    np.savetxt(log, np.column_stack([columns[k] for k in names]), delimiter=",", header=",".join(names.values()),
               comments="", fmt="%.9g")
    assert _run("diagnose", str(log), "--steer-column", "steering", f"--steer-scale={scale}", "--quiet") == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]  # above it argparse prints the usage
    assert "argument --steer-scale: must be a finite, non-zero number" in last and "column" not in last


@pytest.mark.parametrize("sidecar, field", [
    ({"wheelbase_m": 1e-9}, "'wheelbase_m' = 1e-09 is outside the accepted range 0.05-20"),
    ({"wheelbase_m": 2.8, "mass_kg": 1e9}, "'mass_kg' = 1e+09 is outside"),
    ({"wheelbase_m": 2.8, "mass_kg": 1500, "yaw_inertia_kgm2": 1.0}, "'yaw_inertia_kgm2' = 1 is"),
    ({"cg_to_front_m": 0.01, "cg_to_rear_m": 0.01}, "outside the accepted wheelbase range"),
], ids=["wheelbase-1e-9", "mass-1e9", "inertia-1", "cg-tiny"])
def test_nonsense_sidecar_values_are_refused_naming_the_field(tmp_path, capsys, base_recording, sidecar, field):
    path = _csv(tmp_path, base_recording)
    (tmp_path / "rec.json").write_text(json.dumps(sidecar))
    assert _run("diagnose", str(path), "--quiet") == 2
    assert field in capsys.readouterr().err


def test_recording_bounds_are_checked_before_any_work(tmp_path, capsys, base_recording, monkeypatch):
    slow = _csv(tmp_path, base_recording, name="slow.csv", t=base_recording.t_s * 25.0)  # 2 Hz
    assert _run("diagnose", str(slow), "--quiet") == 2
    assert "median sampling interval 0.5 s (2 Hz); accepted 0.001-0.2 s" in capsys.readouterr().err
    gap = base_recording.t_s.copy()
    gap[-1] = 1e6  # one row a million seconds later: the uniform grid would not fit in memory
    gappy = _csv(tmp_path, base_recording, name="gap.csv", t=gap)
    assert _run("diagnose", str(gappy), "--quiet") == 2
    assert "at most 14400 s are accepted" in capsys.readouterr().err
    monkeypatch.setattr(recording_module, "MAX_ROWS", 1000)
    assert _run("diagnose", str(_csv(tmp_path, base_recording)), "--quiet") == 2
    assert "more than 1,000 data rows" in capsys.readouterr().err


def test_binary_garbage_and_a_bom(tmp_path, capsys, base_recording):
    garbage = tmp_path / "garbage.csv"
    garbage.write_bytes(b"t,steer\n\xff\xfe\x00\x81" * 10)
    assert _run("diagnose", str(garbage), "--quiet") == 2
    assert "not a text CSV" in capsys.readouterr().err
    path = _csv(tmp_path, base_recording)
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert read_recording(bom).n == base_recording.n


def test_zero_steering_is_unexcited_never_a_match():
    rng = np.random.default_rng(2)
    t = np.arange(2001) * 0.02
    straight = recording_module.recording_from_arrays({
        "t": t, "steer": np.zeros(t.size), "speed": np.full(t.size, 20.0) + 0.05 * rng.standard_normal(t.size),
        "x": 20.0 * t + 0.05 * rng.standard_normal(t.size), "y": 0.05 * rng.standard_normal(t.size),
        "heading": 0.002 * rng.standard_normal(t.size), "yaw_rate": 0.005 * rng.standard_normal(t.size)})
    result = to_json(diagnose(straight))
    assert result["verdict"] == "unexcited" and result["effects"] == []
    assert "Unexcited" in result["summary"]


def test_zero_steering_while_the_car_turns_is_unexplained(base_recording):
    """The steer column is dead (or --steer-scale 0 slipped through another tool): never a match."""
    dead = recording_module.replace(base_recording, steer_rad=np.zeros(base_recording.n))
    result = to_json(diagnose(dead))
    assert result["verdict"] == "unexplained"
    assert "check the steer column" in result["summary"]


def test_little_usable_data_is_low_confidence_with_the_numbers():
    recording, _ = make_recording({"transport_delay": 0.15}, rng=np.random.default_rng(5), duration_s=60.0)
    speed = recording.speed_mps.copy()
    speed[: int(0.6 * recording.n)] = 0.0  # parked for 36 s of 60
    result = to_json(diagnose(recording_module.replace(recording, speed_mps=speed)))
    assert result["confidence"] == "low"
    assert "Low confidence: only" in result["summary"] and "of the 60.0 s recording are scored" in result["summary"]
    assert any("not scored: slower than the speed floor" in w for w in result["warnings"])
    assert result["verdict"] != "match"


def test_the_moving_rms_has_no_negative_variances():
    """A running-sum filter left -1e-17 'variances' after large values (sqrt -> NaN, RuntimeWarning)."""
    t = np.arange(3000) * 0.02
    steer = np.where(t < 30, 0.5 * np.sin(40 * t), 1e-9 * np.sin(t))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        freq = steering_frequency_hz(t, steer)
    assert np.all(np.isfinite(freq))


def test_the_runner_up_text_has_the_right_sign_and_ties_only_inside_the_spread(base_recording):
    problem = make_problem(base_recording)
    plain = fit_candidate(problem, ())
    delay = fit_candidate(problem, ("transport_delay",))
    lag = fit_candidate(problem, ("actuator_lag",))

    def text(winner, runner, margin, ci, reason="r"):
        return runner_up_text(Selection("mismatch", winner, winner, runner, plain, 9.0, margin, [winner, runner],
                                        reason, margin_ci=ci), "rad/s")

    better = text(plain, delay, -0.457, (-0.5, -0.4))
    assert "scores 45.7% better than plain" in better and "not chosen" in better and "worse" not in better
    assert "cannot tell them apart" not in better
    tie = text(delay, lag, 0.005, (-0.01, 0.02))
    assert "cannot tell them apart" in tie and "quick steering (above ~1 Hz) separates them" in tie
    clear = text(delay, lag, 0.3, (0.2, 0.4))
    assert "30.0% worse" in clear and "cannot tell" not in clear


def test_make_recording_refuses_nonsense(tmp_path, capsys):
    out = str(tmp_path / "r.csv")
    for argv, message in [
        (["--rate-hz", "2"], "argument --rate-hz: 2 is outside the accepted range [5, 1000]"),
        (["--duration-s", "nan"], "argument --duration-s: nan is outside the accepted range"),
        (["--effect", "delay_jitter=abc"], "'abc' is not a number"),
        (["--effect", "road_bank=2"], "bank_rad = 2.0 is outside"),
        (["--effect", "delay_jitter=0.03,colour=1"], "unknown parameter(s) colour"),
        (["--timestamp-jitter", "0.9"], "argument --timestamp-jitter: 0.9 is outside the accepted range [0, 0.5]"),
        (["--car", "small", "--model", "commonroad-mb"], "brings its own car"),
    ]:
        assert _run("make-recording", "--out", out, *argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert not list(tmp_path.iterdir())


def test_make_recording_writes_irregular_rows_that_diagnose_reads(tmp_path, capsys):
    out = tmp_path / "small.csv"
    assert _run("make-recording", "--car", "small", "--effect", "transport_delay=0.08", "--rate-hz", "20",
                "--timestamp-jitter", "0.2", "--drop-rows", "0.05", "--duration-s", "60", "--seed", "3",
                "--out", str(out)) == 0
    rec = read_recording(out)
    assert any("resampled" in w for w in rec.warnings) and rec.vehicle.wheelbase_m == pytest.approx(0.3302)
    report = tmp_path / "d.json"
    assert _run("diagnose", str(out), "--json", str(report), "--quiet") == 0
    data = json.loads(report.read_text())
    assert [e["name"] for e in data["effects"]] == ["transport_delay"]
    assert abs(data["effects"][0]["params"]["delay_s"] - 0.08) < 0.01
    assert math.isfinite(data["fit"]["noise_sigma"])


def test_write_recording_keeps_irregular_times(tmp_path):
    rec, _ = make_recording({}, rng=np.random.default_rng(0), duration_s=20.0, model="kinematic",
                            timestamp_jitter=0.3, drop_fraction=0.1)
    assert not rec.is_uniform
    back = read_recording(write_recording(rec, tmp_path / "irregular.csv"))
    assert back.is_uniform and any("resampled" in w for w in back.warnings)
    assert back.raw is not None and len(back.raw["t"]) == rec.n
