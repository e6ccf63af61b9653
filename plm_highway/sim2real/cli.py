"""``plm-highway sim2real diagnose`` and ``plm-highway sim2real make-recording``.

Bad input raises ValueError/FileNotFoundError (the router prints "error: ..." and exits 2);
warnings about still-usable data go to stderr. Output files are written whole or not at all.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from plm_highway.sim2real.effects import EFFECT_NAMES


def configure(parser: argparse.ArgumentParser) -> None:
    command = parser.get_default("command")
    if command == "sim2real diagnose":
        parser.add_argument("recording", help="recording CSV (sidecar <stem>.json read when present)")
        parser.add_argument("--json", metavar="OUT.json", help="write the diagnosis as JSON")
        parser.add_argument("--report", metavar="DIR", help="write figures and summary.md into DIR")
        parser.add_argument("--sidecar", metavar="CAR.json", help="vehicle sidecar (default: <stem>.json)")
        parser.add_argument("--anchor-s", type=float, default=2.0,
                            help="re-anchor the replayed pose to the recording every this many seconds (2)")
        parser.add_argument("--block-s", type=float, default=None,
                            help="length of the alternating cross-validation blocks (default: duration/16 in 2.5-8 s)")
        parser.add_argument("--split", choices=["blocks", "halves"], default="blocks",
                            help="held-out data: 2-fold alternating blocks (default) or fit the first half, "
                                 "score the second")
        parser.add_argument("--signal", choices=["auto", "yaw_rate", "heading"], default="auto",
                            help="signal to fit: the recorded yaw rate (auto, when present) or the heading's "
                                 "derivative")
        parser.add_argument("--steer-column", metavar="NAME",
                            help="read a simulator log instead: the steering command column (see read_sim_log)")
        parser.add_argument("--steer-scale", type=float, default=1.0,
                            help="with --steer-column: multiply the command by this to get radians "
                                 "(0.2 for this project's env logs, whose steering is normalised)")
        parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    elif command == "sim2real make-recording":
        parser.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE]",
                            help=f"concealed effect, repeatable; one of {', '.join(EFFECT_NAMES)}. Values: "
                                 "delay_s, time_constant_s, understeer gradient [rad/(m/s^2)], gain, offset_rad")
        parser.add_argument("--model", default="auto",
                            choices=["auto", "simulator", "kinematic", "single-track", "commonroad-st",
                                     "commonroad-mb"],
                            help="vehicle physics (auto: single-track with tire_slip, else kinematic)")
        parser.add_argument("--seed", type=int, default=0, help="random seed (inputs and noise)")
        parser.add_argument("--out", required=True, metavar="REC.csv", help="output CSV (+ sidecar, + .truth.json)")
        parser.add_argument("--duration-s", type=float, default=120.0, help="length of the recording [s]")
        parser.add_argument("--rate-hz", type=float, default=50.0, help="sample rate [Hz]")
        parser.add_argument("--noise-scale", type=float, default=1.0, help="multiply every noise level")
        parser.add_argument("--no-yaw-rate", action="store_true", help="leave out the yaw_rate column")
        parser.add_argument("--no-lat-accel", action="store_true", help="leave out the lat_accel column")
    else:  # pragma: no cover - the router only sends the two commands above
        raise ValueError(f"unknown command {command!r}")


def parse_effect_specs(specs: list[str]) -> dict[str, float | None]:
    out: dict[str, float | None] = {}
    for spec in specs:
        name, _, value = spec.partition("=")
        name = name.strip()
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        if name in out:
            raise ValueError(f"effect {name!r} given twice")
        if value:
            try:
                out[name] = float(value)
            except ValueError:
                raise ValueError(f"--effect {spec}: {value!r} is not a number") from None
        else:
            out[name] = None
    return out


def _run_diagnose(args) -> int:
    from plm_highway.io import check_target
    from plm_highway.sim2real.diagnose import diagnose, to_json
    from plm_highway.sim2real.recording import SIMULATOR_VEHICLE, read_recording, read_sidecar, read_sim_log
    from plm_highway.sim2real.report import DIAGNOSIS_JSON, SIM2REAL_REPORT, publish_diagnosis

    started = time.perf_counter()
    if args.anchor_s <= 0:
        raise ValueError("--anchor-s must be positive")
    if args.block_s is not None and args.block_s <= 0:
        raise ValueError("--block-s must be positive")
    if args.steer_column:
        vehicle = SIMULATOR_VEHICLE
        if args.sidecar:
            vehicle, notes = read_sidecar(Path(args.sidecar))
            for note in notes:
                print(f"warning: {note}", file=sys.stderr)
        recording = read_sim_log(args.recording, steer_column=args.steer_column, steer_scale=args.steer_scale,
                                 vehicle=vehicle)
    else:
        recording = read_recording(args.recording, sidecar=args.sidecar)
    sidecar = Path(args.sidecar) if args.sidecar else Path(args.recording).with_suffix(".json")
    for output, kind in ((args.json, DIAGNOSIS_JSON), (args.report, SIM2REAL_REPORT)):
        if output and Path(output).resolve() in (sidecar.resolve(), Path(args.recording).resolve()):
            raise ValueError(f"{output} would overwrite the recording or its sidecar; choose another output path")
        if output:
            check_target(output, kind, overwrite=args.overwrite)
    for warning in recording.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    result = diagnose(recording, block_s=args.block_s, anchor_s=args.anchor_s, split=args.split,
                      signal_name=args.signal)
    for note in result.notes:
        print(f"warning: {note}", file=sys.stderr)
    data = to_json(result)
    data["elapsed_s"] = time.perf_counter() - started
    if args.json or args.report:
        publish_diagnosis(result, data, args.json, args.report, overwrite=args.overwrite)
    if not args.quiet:
        print(result.summary)
        print(f"verdict: {result.verdict} ({time.perf_counter() - started:.1f} s)")
    return 0


def _run_make_recording(args) -> int:
    import numpy as np

    from plm_highway.io import check_target
    from plm_highway.sim2real.recording import RECORDING_CSV, write_recording
    from plm_highway.sim2real.synth import NoiseLevels, make_recording

    if args.rate_hz <= 0 or args.noise_scale < 0:
        raise ValueError("--rate-hz must be positive and --noise-scale non-negative")
    effects = parse_effect_specs(args.effect)
    check_target(args.out, RECORDING_CSV, overwrite=args.overwrite)
    recording, truth = make_recording(
        effects, rng=np.random.default_rng(args.seed), duration_s=args.duration_s, sample_hz=args.rate_hz,
        model=args.model, noise=NoiseLevels().scaled(args.noise_scale), with_yaw_rate=not args.no_yaw_rate,
        with_lat_accel=not args.no_lat_accel,
    )
    out = Path(args.out)
    truth["seed"] = args.seed
    write_recording(recording, out, truth=truth, overwrite=args.overwrite)
    print(f"wrote {out} ({recording.n} samples, {recording.duration_s:.0f} s, model {truth['model']}, "
          f"effects: {', '.join(truth['effects']) or 'none'})")
    return 0


def run(args) -> int:
    if args.command == "sim2real diagnose":
        return _run_diagnose(args)
    return _run_make_recording(args)
