"""The diagnosis on concealed physics: right effects named, parameters recovered, fit improved on
held-out data; no false alarms on the simulator's own model; the slip-looks-like-delay trap; the
multi-body model; the real recording when it is present; and the 10-minute timing."""

from __future__ import annotations

import functools
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from plm_highway.cli import main
from plm_highway.sim2real.diagnose import diagnose
from plm_highway.sim2real.physics.effects import EFFECT_NAMES, EFFECT_PARAM_KEYS
from plm_highway.sim2real.physics.synth import NoiseLevels, make_recording
from plm_highway.sim2real.record.recording import read_recording
from plm_highway.sim2real.rendering import to_json
from plm_highway.vehicle.kinematic import kinematic_bicycle_rates

REAL_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "real"
NOISE = NoiseLevels()
SEEDS_PER_CASE = 3

# Values the concealed effects take, one per seed.
VALUES = {
    "transport_delay": [0.08, 0.15, 0.30],
    "actuator_lag": [0.08, 0.15, 0.30],
    "tire_slip": [None, 0.003, 0.002],  # None: the seed paper's car (K = 0.00144 rad/(m/s^2))
    "steering_gain": [0.90, 1.10, 0.85],
    "steering_offset": [0.004, -0.006, 0.008],
}
# The original five effects, alone and in pairs (the extended library: tests/test_sim2real_library.py).
ORIGINAL_EFFECTS = tuple(VALUES)
CASES = [(name,) for name in ORIGINAL_EFFECTS] + list(itertools.combinations(ORIGINAL_EFFECTS, 2))


def recovered(name: str, key: str, estimate: float, truth: float) -> bool:
    """The issue's tolerances."""
    error = abs(estimate - truth)
    if key == "delay_s":
        return error <= max(0.010, 0.10 * truth)
    if key == "time_constant_s":
        return error <= 0.20 * truth
    if key == "gain":
        return error <= 0.03 * truth
    if key == "offset_rad":
        return error <= 0.002
    if key == "understeer_gradient_rad_per_mps2":
        return error <= 0.20 * truth
    return True  # cornering stiffnesses individually: reported, not graded


@functools.cache
def _case(effects: tuple[str, ...], index: int):
    seed = 7919 * (CASES.index(effects) + 1) + index
    spec = {name: VALUES[name][index] for name in effects}
    recording, truth = make_recording(spec, rng=np.random.default_rng(seed), duration_s=120.0)
    return recording, truth, to_json(diagnose(recording))


@pytest.mark.slow
@pytest.mark.parametrize("index", range(SEEDS_PER_CASE))
@pytest.mark.parametrize("effects", CASES, ids=lambda c: "+".join(c))
def test_concealed_effects_are_named_recovered_and_explained(effects, index):
    _, truth, result = _case(effects, index)
    found = {e["name"]: e for e in result["effects"]}
    assert result["verdict"] == "mismatch"
    assert set(found) == set(effects), f"named {sorted(found)}, concealed {sorted(effects)}: {result['summary']}"
    for name, params in truth["effects"].items():
        for key, value in params.items():
            estimate = found[name]["params"][key]
            assert recovered(name, key, estimate, value), f"{name}.{key}: {estimate:.5g} vs truth {value:.5g}"
            lo, hi = found[name]["ci"][key]
            assert lo <= estimate <= hi
    fit = result["fit"]
    assert fit["heldout"] and fit["signal"] == "yaw_rate"
    assert fit["rmse_after"] <= max(0.2 * fit["rmse_before"], 1.25 * NOISE.yaw_rate_radps), fit
    assert fit["rmse_after"] >= 0.9 * NOISE.yaw_rate_radps  # nothing fits below the noise
    assert fit["noise_sigma"] == pytest.approx(NOISE.yaw_rate_radps, rel=0.15)
    assert result["runner_up"]["name"] != " + ".join(e for e in EFFECT_NAMES if e in effects)


@pytest.mark.slow
def test_the_simulators_own_model_plus_noise_matches_in_95_percent_of_seeds():
    verdicts = []
    for seed in range(20):
        recording, _ = make_recording({}, rng=np.random.default_rng(50_000 + seed), duration_s=60.0,
                                      model="simulator")
        result = diagnose(recording)
        verdicts.append(result.verdict)
        assert result.fit["rmse_before"] < 1.1 * NOISE.yaw_rate_radps
    assert verdicts.count("match") >= 19, verdicts


def test_a_match_reports_no_effects_and_no_change(tmp_path):
    recording, _ = make_recording({}, rng=np.random.default_rng(3), duration_s=40.0, model="kinematic")
    result = to_json(diagnose(recording))
    assert result["verdict"] == "match" and result["effects"] == []
    assert result["fit"]["rmse_after"] == result["fit"]["rmse_before"]
    assert "No significant mismatch" in result["summary"]
    assert result["runner_up"]["name"] != "plain"


def _xcorr_lag_s(recording) -> float:
    """The delay input-output cross-correlation would name: the shift of the plain model's yaw rate
    that best matches the recorded one."""
    plain, _ = kinematic_bicycle_rates(recording.steer_rad, recording.speed_mps, recording.vehicle.kinematic)
    measured = recording.yaw_rate_radps
    lags = np.arange(0, 20)
    errors = [np.mean((measured[20:] - plain[20 - lag: len(plain) - lag]) ** 2) for lag in lags]
    return float(lags[int(np.argmin(errors))] * recording.dt_s)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(SEEDS_PER_CASE))
def test_tire_slip_looks_like_a_delay_but_is_named_tire_slip(index):
    recording, _, result = _case(("tire_slip",), index)
    assert _xcorr_lag_s(recording) >= 0.04  # the trap: cross-correlation sees a lag
    assert [e["name"] for e in result["effects"]] == ["tire_slip"]
    assert "transport_delay" not in result["runner_up"]["effects"] or result["runner_up"]["margin"] > 0.2


@pytest.mark.slow
def test_multi_body_commonroad_recording_improves_by_half_on_held_out_data():
    recording, _ = make_recording({}, rng=np.random.default_rng(11), duration_s=60.0, model="commonroad-mb")
    result = to_json(diagnose(recording))
    assert result["verdict"] == "mismatch"
    assert "tire_slip" in [e["name"] for e in result["effects"]]
    fit = result["fit"]
    assert fit["rmse_after"] <= 0.5 * fit["rmse_before"], fit


@pytest.mark.slow
def test_commonroad_single_track_is_neutral_steer_slip_not_a_delay():
    recording, _ = make_recording({}, rng=np.random.default_rng(12), duration_s=60.0, model="commonroad-st")
    result = to_json(diagnose(recording))
    found = {e["name"]: e for e in result["effects"]}
    assert "tire_slip" in found
    assert abs(found["tire_slip"]["params"]["understeer_gradient_rad_per_mps2"]) < 3e-4
    assert found.get("transport_delay", {"params": {"delay_s": 0}})["params"]["delay_s"] < 0.03  # the 10-ms servo


def test_without_a_yaw_rate_the_heading_is_differentiated():
    recording, _ = make_recording({"transport_delay": 0.2}, rng=np.random.default_rng(21), duration_s=90.0,
                                  with_yaw_rate=False)
    result = to_json(diagnose(recording))
    assert result["fit"]["signal"] == "heading_rate"
    assert [e["name"] for e in result["effects"]] == ["transport_delay"]
    # The heading follows the simulator's Euler convention: continuous data read dt/2 (10 ms) early.
    assert result["effects"][0]["params"]["delay_s"] == pytest.approx(0.2, abs=0.02)
    assert result["fit"]["heading_rmse_after_rad"] < 0.3 * result["fit"]["heading_rmse_before_rad"]


def test_cli_make_recording_then_diagnose_writes_json_and_report(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    assert main(["sim2real", "make-recording", "--effect", "actuator_lag=0.2", "--effect", "steering_offset",
                 "--seed", "4", "--duration-s", "60", "--out", str(rec)]) == 0
    truth = json.loads((tmp_path / "rec.truth.json").read_text())
    assert truth["effects"]["actuator_lag"] == {"time_constant_s": 0.2}
    out, report = tmp_path / "diag.json", tmp_path / "report"
    assert main(["sim2real", "diagnose", str(rec), "--json", str(out), "--report", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "actuator lag" in printed and "held-out" in printed
    data = json.loads(out.read_text())
    assert set(data) >= {"verdict", "effects", "runner_up", "fit", "windows", "conditions"}
    assert set(data["fit"]) >= {"signal", "rmse_before", "rmse_after", "noise_sigma", "heldout"}
    assert {e["name"] for e in data["effects"]} == {"actuator_lag", "steering_offset"}
    for effect in data["effects"]:
        assert set(effect) == {"name", "params", "ci"}
        assert set(effect["params"]) <= set(EFFECT_PARAM_KEYS[effect["name"]])
    assert set(data["conditions"]) >= {"speed_mps", "abs_lat_accel_mps2", "steer_freq_hz", "direction"}
    assert all(len(w) == 2 and w[0] < w[1] for w in data["windows"])
    names = sorted(p.name for p in report.iterdir())
    assert names == [".plm-highway-output.json", "candidates.png", "conditions.png", "diagnosis.json", "overlay.png",
                     "residuals.png", "summary.md"]
    assert not [p for p in tmp_path.rglob("*.tmp*")]


def test_make_recording_rejects_unknown_effects(capsys):
    assert main(["sim2real", "make-recording", "--effect", "wind", "--out", "x.csv"]) == 2
    assert "unknown effect 'wind'" in capsys.readouterr().err


@pytest.mark.slow
def test_ten_minutes_at_50_hz_are_diagnosed():
    # How long this takes is measured by a benchmark, not asserted here (tests do not time themselves).
    recording, _ = make_recording({"transport_delay": 0.2, "tire_slip": None}, rng=np.random.default_rng(5),
                                  duration_s=600.0, sample_hz=50.0)
    assert recording.n == 30_001
    result = diagnose(recording)
    assert result.verdict == "mismatch"


@pytest.mark.skipif(not (REAL_DIR / "iac_putnam_run4_2.csv").is_file(), reason="../shared/real is absent")
def test_real_recording_beats_the_earlier_quick_analysis():
    recording = read_recording(REAL_DIR / "iac_putnam_run4_2.csv")
    result = to_json(diagnose(recording))
    # A race car at the limit on a real track: tire slip and a late gyro explain most of the error,
    # and what is left is still structured (it correlates with the steering rate).
    assert result["verdict"] in ("mismatch", "partly explained")
    names = {e["name"] for e in result["effects"]}
    assert "tire_slip" in names
    fit = result["fit"]
    assert fit["rmse_after"] / fit["rmse_before"] - 1 < -0.69, fit  # earlier: -65% (quick analysis), -69% (v1)
    lag = result["checks"]["yaw_rate_lag_behind_heading"]["lag_s"]
    assert 0.2 < lag < 0.5
    assert any("runs" in w and "late against the derivative of the recorded heading" in w for w in result["warnings"])
    assert math.isfinite(fit["noise_sigma"])
    # The library leaves structure, so residual discovery runs; what it names is plausible and said in
    # the summary, and when it names nothing the summary says so and the library's verdict stands.
    discovery = result["discovery"]
    assert discovery is not None and len(discovery["tried"]) >= 6, discovery
    assert all(f["plausible"] for f in discovery["found"])
    if discovery["found"]:
        assert result["verdict"] == "discovered"
        assert "Discovered outside the library" in result["summary"]
    else:
        assert result["verdict"] == result["library_verdict"]
        assert "no term outside the library improves held-out data" in result["summary"]
