"""A diagnosis of a recording file and a synthetic recording file, end to end, with typed arguments.

The command line (``plm_highway/cli/sim2real.py``) only parses options and calls these. Bad input
raises :class:`plm_highway.errors.BadInput` (exit 2 on the command line); warnings about
still-usable data go to stderr. Outputs go through :mod:`plm_highway.io`: published whole or not
at all, and never over anything plm-highway did not write.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from plm_highway.errors import BadInput
from plm_highway.io import check_target
from plm_highway.io.bounded import parse_float_text
from plm_highway.sim2real.diagnose import diagnose
from plm_highway.sim2real.perception_delay import diagnosis_delays, perception_delay, perception_delay_lines
from plm_highway.sim2real.physics.effects import EFFECT_NAMES, EFFECTS
from plm_highway.sim2real.physics.replay import ANCHOR_S
from plm_highway.sim2real.physics.synth import OUTSIDE_EFFECTS, NoiseLevels, make_recording
from plm_highway.sim2real.record.recording import (
    RECORDING_CSV,
    SIMULATOR_VEHICLE,
    read_recording,
    read_sidecar,
    read_sim_log,
    write_recording,
)
from plm_highway.sim2real.rendering import to_json
from plm_highway.sim2real.report import DIAGNOSIS_JSON, SIM2REAL_REPORT, publish_diagnosis


def parse_effect_specs(specs: list[str]) -> dict[str, dict[str, float] | None]:
    """``NAME``, ``NAME=VALUE`` (its first parameter) or ``NAME=VALUE,KEY=VALUE,...``."""

    known = (*EFFECT_NAMES, *OUTSIDE_EFFECTS)
    out: dict[str, dict[str, float] | None] = {}
    for spec in specs:
        name, _, rest = spec.partition("=")
        name = name.strip()
        if name not in known:
            raise BadInput(f"--effect {spec}: unknown effect {name!r}; known: {', '.join(known)}")
        if name in out:
            raise BadInput(f"--effect {spec}: effect {name!r} given twice")
        if not rest:
            out[name] = None
            continue
        primary = EFFECTS[name].primary_synth_key if name in EFFECTS else OUTSIDE_EFFECTS[name][0]
        values: dict[str, float] = {}
        for item in rest.split(","):
            key, eq, text = item.partition("=")
            key, text = (key.strip(), text) if eq else (primary, key)
            values[key] = parse_float_text(text, f"--effect {spec}: {key}", non_finite=True)
            if not math.isfinite(values[key]):
                raise BadInput(f"--effect {spec}: {key} must be a finite number, got {text!r}")
        out[name] = values
    return out


def diagnose_file(
    recording_path: str | os.PathLike,
    *,
    json_path: str | os.PathLike | None = None,
    report_dir: str | os.PathLike | None = None,
    sidecar: str | os.PathLike | None = None,
    anchor_s: float = ANCHOR_S,
    block_s: float | None = None,
    split: str = "blocks",
    signal: str = "auto",
    steer_column: str | None = None,
    steer_scale: float = 1.0,
    discovery: str = "auto",
    quiet: bool = False,
    overwrite: bool = False,
) -> int:
    """Read a recording (or, with ``steer_column``, a simulator log), diagnose it, print the summary and
    publish the JSON and/or report. Returns the exit code (0)."""

    started = time.perf_counter()
    if not (math.isfinite(steer_scale) and steer_scale != 0):
        raise BadInput(f"--steer-scale must be a finite, non-zero number, got {steer_scale!r}")
    if steer_scale != 1.0 and not steer_column:
        raise BadInput("--steer-scale applies to simulator logs only (with --steer-column)")
    recording_path = Path(recording_path)
    sidecar_path = Path(sidecar) if sidecar else recording_path.with_suffix(".json")
    for output, kind in ((json_path, DIAGNOSIS_JSON), (report_dir, SIM2REAL_REPORT)):
        if output and Path(output).resolve() in (sidecar_path.resolve(), recording_path.resolve()):
            raise BadInput(f"{output} would overwrite the recording or its sidecar; choose another output path")
        if output:  # refuse before the work, not after
            check_target(output, kind, overwrite=overwrite)
    if steer_column:
        vehicle = SIMULATOR_VEHICLE
        if sidecar:
            vehicle, notes = read_sidecar(Path(sidecar))
            for note in notes:
                print(f"warning: {note}", file=sys.stderr)
        recording = read_sim_log(recording_path, steer_column=steer_column, steer_scale=steer_scale,
                                 vehicle=vehicle)
    else:
        recording = read_recording(recording_path, sidecar=sidecar)
    for warning in recording.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    try:
        result = diagnose(recording, block_s=block_s, anchor_s=anchor_s, split=split, signal_name=signal,
                          discovery=discovery)
    except ValueError as exc:  # input problems found late: name the file the user gave, not only its short name
        raise BadInput(f"{recording_path}: {exc}") from None
    for note in result.notes:
        print(f"warning: {note}", file=sys.stderr)
    data = to_json(result)
    perception_lines = _perception_delay(recording_path, result, data)
    data["elapsed_s"] = time.perf_counter() - started
    if json_path or report_dir:
        publish_diagnosis(result, data, json_path, report_dir, overwrite=overwrite, extra_lines=perception_lines)
    if not quiet:
        print(result.summary)
        print(perception_lines[2])
        confidence = ", low confidence" if result.confidence == "low" else ""
        print(f"verdict: {result.verdict}{confidence} ({time.perf_counter() - started:.1f} s)")
    return 0


def _perception_delay(recording_path: Path, result, data: dict) -> list[str]:
    """The camera's perception delay beside the diagnosis's delays (:mod:`plm_highway.sim2real.perception_delay`):
    added to ``data``; the report's lines returned."""

    found = perception_delay(recording_path, vehicle_params=result.recording.vehicle.kinematic)
    delays = diagnosis_delays(result)
    data["perception_delay"] = {**found, "diagnosis_delays_s": delays}
    return perception_delay_lines(found, delays)


def make_recording_file(
    out: str | os.PathLike,
    effects: list[str] | None = None,
    *,
    model: str = "auto",
    car: str = "auto",
    seed: int = 0,
    duration_s: float = 120.0,
    rate_hz: float = 50.0,
    noise_scale: float = 1.0,
    yaw_rate: bool = True,
    lat_accel: bool = True,
    timestamp_jitter: float = 0.0,
    drop_rows: float = 0.0,
    overwrite: bool = False,
) -> int:
    """Synthesise a recording with concealed physics (``effects``: ``NAME[=VALUE[,KEY=VALUE...]]``) and
    write ``out`` with its sidecar and ``STEM.truth.json``. Returns the exit code (0)."""

    parsed = parse_effect_specs(list(effects or []))
    check_target(out, RECORDING_CSV, overwrite=overwrite)
    recording, truth = make_recording(
        parsed, rng=np.random.default_rng(seed), duration_s=duration_s, sample_hz=rate_hz, model=model,
        noise=NoiseLevels().scaled(noise_scale), with_yaw_rate=yaw_rate, with_lat_accel=lat_accel, car=car,
        timestamp_jitter=timestamp_jitter, drop_fraction=drop_rows,
    )
    out = Path(out)
    truth["seed"] = seed
    write_recording(recording, out, truth=truth, overwrite=overwrite)
    print(f"wrote {out} ({recording.n} samples, {recording.duration_s:.0f} s, model {truth['model']}, "
          f"effects: {', '.join(truth['effects']) or 'none'})")
    return 0
