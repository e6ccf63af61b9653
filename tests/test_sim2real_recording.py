"""Recordings in and out: the format, bad input (clear errors, exit code 2), sim logs, atomic writes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

from plm_highway.cli import main
from plm_highway.io import file_kind, write_output
from plm_highway.sim2real.physics.replay import plain_replay
from plm_highway.sim2real.record.recording import (
    SIMULATOR_VEHICLE,
    Recording,
    VehicleGeometry,
    read_recording,
    read_sim_log,
    write_recording,
)


def _rows(n=800, dt=0.02, steer_scale=1.0):
    t = np.arange(n) * dt
    steer = 0.03 * np.sin(2 * math.pi * 0.3 * t) * steer_scale
    speed = np.full(n, 15.0)
    heading = np.cumsum(np.full(n, 0.01))
    return {"t": t, "steer": steer, "speed": speed, "x": 15 * t, "y": np.zeros(n), "heading": heading}


def _write_csv(path, columns: dict, fmt="%.6f"):
    names = list(columns)
    np.savetxt(path, np.column_stack([columns[k] for k in names]), delimiter=",", header=",".join(names),
               comments="", fmt=fmt)
    return path


def _diagnose(path, *extra):
    return main(["sim2real", "diagnose", str(path), "--quiet", *extra])


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda c: c.pop("speed"), "missing column(s) speed"),
        (lambda c: c["x"].__setitem__(17, np.nan), "column 'x' is NaN on line 19"),
        (lambda c: c["steer"].__setitem__(40, np.inf), "column 'steer' is infinite on line 42"),
        (lambda c: c["t"].__setitem__(100, c["t"][99]), "duplicate time"),
        (lambda c: c["t"].__setitem__(100, c["t"][98]), "decreasing time"),
        (lambda c: c.__setitem__("steer", np.degrees(c["steer"]) + 5.0), "looks like degrees"),
    ],
    ids=["missing", "nan", "inf", "duplicate-time", "decreasing-time", "degrees"],
)
def test_bad_input_is_a_clear_error_with_exit_code_2(tmp_path, capsys, mutate, message):
    columns = _rows()
    mutate(columns)
    path = _write_csv(tmp_path / "bad.csv", columns)
    out_json = tmp_path / "out.json"
    assert _diagnose(path, "--json", str(out_json)) == 2
    err = capsys.readouterr().err
    assert "error:" in err and message in err, err
    assert not out_json.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["bad.csv"]  # no partial output, no temp files


def test_too_short_a_recording_is_refused(tmp_path, capsys):
    path = _write_csv(tmp_path / "short.csv", _rows(n=400))  # 8 s
    assert _diagnose(path) == 2
    assert "at least 10 s" in capsys.readouterr().err


def test_a_non_number_names_its_line(tmp_path, capsys):
    path = _write_csv(tmp_path / "text.csv", _rows())
    lines = path.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[2], "fast", 1)
    path.write_text("\n".join(lines) + "\n")
    assert _diagnose(path) == 2
    assert "line 6" in capsys.readouterr().err


def test_missing_file_is_exit_code_2(tmp_path, capsys):
    assert _diagnose(tmp_path / "nope.csv") == 2
    assert "no such file" in capsys.readouterr().err


def test_unknown_sidecar_keys_warn_but_load(tmp_path):
    path = _write_csv(tmp_path / "run.csv", _rows())
    (tmp_path / "run.json").write_text(json.dumps({"wheelbase_m": 2.8, "cg_to_front_m": 1.3, "colour": "red"}))
    rec = read_recording(path)
    assert rec.vehicle.cg_to_rear_m == pytest.approx(1.5)
    assert any("unknown key(s) colour" in w for w in rec.warnings)


@pytest.mark.parametrize("sidecar, message", [
    ({"wheelbase_m": -1}, "'wheelbase_m' must be a positive number"),
    ({"wheelbase_m": 2.8, "cg_to_front_m": 1.0, "cg_to_rear_m": 1.0}, "wheelbase_m = 2.800"),
    ({"cg_to_front_m": 1.2}, "give wheelbase_m or both"),
])
def test_inconsistent_sidecars_are_errors(tmp_path, sidecar, message):
    path = _write_csv(tmp_path / "run.csv", _rows())
    (tmp_path / "run.json").write_text(json.dumps(sidecar))
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        read_recording(path)


def test_only_a_wheelbase_puts_the_reference_point_in_the_middle(tmp_path):
    path = _write_csv(tmp_path / "run.csv", _rows())
    (tmp_path / "run.json").write_text(json.dumps({"wheelbase_m": 3.0, "mass_kg": 1500}))
    rec = read_recording(path)
    assert (rec.vehicle.cg_to_front_m, rec.vehicle.cg_to_rear_m, rec.vehicle.mass_kg) == (1.5, 1.5, 1500)
    assert not rec.vehicle.inertia_known and rec.vehicle.yaw_inertia_per_kg_m2 == pytest.approx(2.25)


def test_brief_big_steering_and_jitter_warn_but_load(tmp_path):
    columns = _rows()
    columns["steer"][300] = 1.2  # one sample, not sustained
    columns["t"] = columns["t"] + np.random.default_rng(0).uniform(-0.003, 0.003, len(columns["t"]))
    columns["t"][0] = 0.0
    columns["yaw_rate"] = np.full(len(columns["t"]), 0.5)
    columns["yaw_rate"][50] = np.nan
    path = _write_csv(tmp_path / "run.csv", columns)
    rec = read_recording(path)
    text = " ".join(rec.warnings)
    assert "exceeds 1 rad briefly" in text and "resampled" in text and "column 'yaw_rate' is NaN" in text
    assert rec.yaw_rate_radps is None
    np.testing.assert_allclose(np.diff(rec.t_s), rec.dt_s, atol=1e-9)


def test_heading_glitch_is_flagged_and_left_out(tmp_path):
    columns = _rows()
    columns["yaw_rate"] = np.full(len(columns["t"]), 0.5)
    columns["heading"] = np.cumsum(np.full(len(columns["t"]), 0.5 * 0.02))
    columns["heading"][400:] += 0.5
    rec = read_recording(_write_csv(tmp_path / "run.csv", columns))
    assert any("heading jumps by +0.51 rad on line 402" in w for w in rec.warnings)
    assert not rec.usable_mask[380:420].any() and rec.usable_mask[300]


def test_write_read_round_trip_with_sidecar(tmp_path):
    columns = _rows()
    geometry = VehicleGeometry(1.2, 1.6, 1500.0, 2400.0, source="test")
    rec = Recording(t_s=columns["t"], steer_rad=columns["steer"], speed_mps=columns["speed"], x_m=columns["x"],
                    y_m=columns["y"], heading_rad=columns["heading"] + 10.0, yaw_rate_radps=np.ones(800) * 0.01,
                    vehicle=geometry)
    path = write_recording(rec, tmp_path / "rt.csv")
    back = read_recording(path)
    np.testing.assert_allclose(back.heading_rad - back.heading_rad[0], rec.heading_rad - rec.heading_rad[0], atol=1e-6)
    np.testing.assert_allclose(back.steer_rad, rec.steer_rad, atol=1e-7)
    assert (back.vehicle.cg_to_front_m, back.vehicle.mass_kg, back.vehicle.yaw_inertia_kgm2) == (1.2, 1500.0, 2400.0)
    assert back.lat_accel_mps2 is None and back.yaw_rate_radps is not None


def test_atomic_output_leaves_nothing_behind_on_failure(tmp_path):
    target = tmp_path / "result.json"
    with pytest.raises(RuntimeError), write_output(target, file_kind("test", "a test file")) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert list(tmp_path.iterdir()) == []


def test_json_output_may_not_overwrite_the_sidecar(tmp_path, capsys):
    path = _write_csv(tmp_path / "run.csv", _rows(n=1000))
    (tmp_path / "run.json").write_text(json.dumps({"wheelbase_m": 2.8}))
    assert _diagnose(path, "--json", str(tmp_path / "run.json")) == 2
    assert "would overwrite" in capsys.readouterr().err
    assert json.loads((tmp_path / "run.json").read_text()) == {"wheelbase_m": 2.8}


def _simulator_log(path, n=600, dt=1 / 20, seed=0):
    """A per-step log of highway-env's own Vehicle with a normalised steering action."""
    rng = np.random.default_rng(seed)
    vehicle = Vehicle(road=None, position=[10.0, -4.0], heading=0.4, speed=22.0)
    rows = []
    action = 0.0
    for k in range(n):
        action = float(np.clip(0.9 * action + 0.05 * rng.standard_normal(), -0.3, 0.3))
        rows.append((k * dt, vehicle.position[0], vehicle.position[1], vehicle.heading, vehicle.speed, action, k % 3))
        vehicle.action = {"steering": action * math.pi / 4, "acceleration": 0.0}
        vehicle.step(dt)
    header = "time,pos_x,pos_y,yaw,v,steering_action,lane"
    np.savetxt(path, np.array(rows), delimiter=",", header=header, comments="", fmt="%.12g")
    return path


def test_sim_log_maps_onto_a_recording_and_replays_exactly(tmp_path):
    path = _simulator_log(tmp_path / "sim.csv")
    rec = read_sim_log(path, t_column="time", x_column="pos_x", y_column="pos_y", heading_column="yaw",
                       speed_column="v", steer_column="steering_action", steer_scale=math.pi / 4)
    assert rec.vehicle == SIMULATOR_VEHICLE and rec.n == 600
    replay = plain_replay(rec, anchor_s=2.0)
    assert np.max(np.abs(replay.heading_error_rad)) < 1e-9
    assert np.max(replay.position_error_m) < 1e-8
    with pytest.raises(ValueError, match="missing column"):
        read_sim_log(path, steer_column="steer")


def test_diagnose_reads_a_sim_log_from_the_cli(tmp_path):
    path = _simulator_log(tmp_path / "sim.csv", n=800)
    # The default column names of read_sim_log are those of the project's evaluate logs: rename the log's.
    text = path.read_text().replace("time,pos_x,pos_y,yaw,v,", "t_s,x_m,y_m,heading_rad,speed_mps,", 1)
    path.write_text(text)
    out = tmp_path / "d.json"
    code = main(["sim2real", "diagnose", str(path), "--steer-column", "steering_action",
                 "--steer-scale", str(math.pi / 4), "--json", str(out), "--quiet"])
    assert code == 0
    data = json.loads(out.read_text())
    assert data["verdict"] == "match" and data["fit"]["signal"] == "heading_rate"


def test_an_evaluate_log_of_the_env_matches_the_simulator_model(tmp_path):
    from plm_highway.evaluation.evaluate import log_rows
    from plm_highway.expert import ExpertPolicy
    from plm_highway.io import write_csv_into
    from plm_highway.rollout.closed_loop import LOG_COLUMNS, drive

    log = drive("reference", ExpertPolicy(), "test", "const:0", seed=0, max_steps=400)  # 20 s at 20 Hz
    path = tmp_path / "out_reference.csv"
    write_csv_into(path, LOG_COLUMNS, log_rows(log))
    out = tmp_path / "d.json"
    code = main(["sim2real", "diagnose", str(path), "--steer-column", "steering", "--steer-scale", "0.2",
                 "--json", str(out), "--quiet"])
    assert code == 0
    assert json.loads(out.read_text())["verdict"] == "match"
