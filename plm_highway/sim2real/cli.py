"""``plm-highway sim2real diagnose`` and ``plm-highway sim2real make-recording``.

Bad input raises ValueError/FileNotFoundError (the router prints "error: ..." and exits 2);
warnings about still-usable data go to stderr. Output files are written whole or not at all.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from plm_highway.sim2real.effects import EFFECT_NAMES, EFFECTS


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
        parser.add_argument("--steer-scale", type=float, default=1.0, metavar="SCALE",
                            help="with --steer-column: multiply the command by this to get radians "
                                 "(0.2 for this project's env logs, whose steering is normalised)")
        parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    elif command == "sim2real make-recording":
        parser.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE[,KEY=VALUE...]]",
                            help="concealed effect, repeatable; VALUE sets its first parameter, KEY=VALUE others: "
                                 + "; ".join(f"{n} ({', '.join(e.synth_defaults)})" for n, e in EFFECTS.items())
                                 + "; outside the library: steering_backlash (width_rad)")
        parser.add_argument("--model", default="auto",
                            choices=["auto", "simulator", "kinematic", "single-track", "commonroad-st",
                                     "commonroad-mb"],
                            help="vehicle physics (auto: single-track when an effect needs tires, else kinematic)")
        parser.add_argument("--car", default="auto", choices=["auto", "sedan", "small"],
                            help="the car and its driving: sedan (seed paper car, 10-30 m/s) or small (1:10 scale "
                                 "F1TENTH car, 0.8-4 m/s); auto: the sedan, or the simulator's 5-m car for a "
                                 "kinematic model")
        parser.add_argument("--seed", type=int, default=0, help="random seed (inputs and noise)")
        parser.add_argument("--out", required=True, metavar="REC.csv", help="output CSV (+ sidecar, + .truth.json)")
        parser.add_argument("--duration-s", type=float, default=120.0)
        parser.add_argument("--rate-hz", type=float, default=50.0)
        parser.add_argument("--noise-scale", type=float, default=1.0, help="multiply every noise level")
        parser.add_argument("--no-yaw-rate", action="store_true", help="leave out the yaw_rate column")
        parser.add_argument("--no-lat-accel", action="store_true", help="leave out the lat_accel column")
        parser.add_argument("--timestamp-jitter", type=float, default=0.0, metavar="FRACTION",
                            help="sample times jitter uniformly by this fraction of the interval (0-0.5)")
        parser.add_argument("--drop-rows", type=float, default=0.0, metavar="FRACTION",
                            help="drop this fraction of the rows at random (0-0.5)")
    else:  # pragma: no cover - the router only sends the two commands above
        raise ValueError(f"unknown command {command!r}")


def parse_effect_specs(specs: list[str]) -> dict[str, dict[str, float] | None]:
    """``NAME``, ``NAME=VALUE`` (its first parameter) or ``NAME=VALUE,KEY=VALUE,...``."""
    from plm_highway.sim2real.synth import OUTSIDE_EFFECTS

    known = (*EFFECT_NAMES, *OUTSIDE_EFFECTS)
    out: dict[str, dict[str, float] | None] = {}
    for spec in specs:
        name, _, rest = spec.partition("=")
        name = name.strip()
        if name not in known:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(known)}")
        if name in out:
            raise ValueError(f"effect {name!r} given twice")
        if not rest:
            out[name] = None
            continue
        primary = EFFECTS[name].primary_synth_key if name in EFFECTS else OUTSIDE_EFFECTS[name][0]
        values: dict[str, float] = {}
        for item in rest.split(","):
            key, eq, text = item.partition("=")
            key, text = (key.strip(), text) if eq else (primary, key)
            try:
                values[key] = float(text)
            except ValueError:
                raise ValueError(f"--effect {spec}: {text!r} is not a number") from None
        out[name] = values
    return out


def finite_option(name: str, value: float, *, nonzero: bool = False) -> float:
    """An option's number, refused (naming the option) when NaN, infinite or, if asked, zero."""
    if not math.isfinite(value) or (nonzero and value == 0):
        raise ValueError(f"{name} must be a finite{', non-zero' if nonzero else ''} number, got {value!r}")
    return value


def _run_diagnose(args) -> int:
    from plm_highway.sim2real.diagnose import diagnose, strict, to_json
    from plm_highway.sim2real.recording import SIMULATOR_VEHICLE, read_recording, read_sidecar, read_sim_log

    started = time.perf_counter()
    finite_option("--anchor-s", args.anchor_s)
    if args.block_s is not None:
        finite_option("--block-s", args.block_s)
    finite_option("--steer-scale", args.steer_scale, nonzero=True)
    if args.steer_scale != 1.0 and not args.steer_column:
        raise ValueError("--steer-scale applies to simulator logs only (with --steer-column)")
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
    for output in (args.json, args.report):
        if output and Path(output).resolve() in (sidecar.resolve(), Path(args.recording).resolve()):
            raise ValueError(f"{output} would overwrite the recording or its sidecar; choose another output path")
    for warning in recording.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    result = diagnose(recording, block_s=args.block_s, anchor_s=args.anchor_s, split=args.split,
                      signal_name=args.signal)
    for note in result.notes:
        print(f"warning: {note}", file=sys.stderr)
    data = to_json(result)
    data["elapsed_s"] = time.perf_counter() - started
    if args.report:
        from plm_highway.sim2real.report import write_report

        write_report(result, args.report)
    if args.json:
        from plm_highway.io.atomic import write_text_atomic

        write_text_atomic(args.json, json.dumps(strict(data), indent=1, allow_nan=False) + "\n")
    if not args.quiet:
        print(result.summary)
        confidence = ", low confidence" if result.confidence == "low" else ""
        print(f"verdict: {result.verdict}{confidence} ({time.perf_counter() - started:.1f} s)")
    return 0


def _run_make_recording(args) -> int:
    import numpy as np

    from plm_highway.io.atomic import write_text_atomic
    from plm_highway.sim2real.diagnose import strict
    from plm_highway.sim2real.recording import write_recording
    from plm_highway.sim2real.synth import NoiseLevels, make_recording

    for name in ("--duration-s", "--rate-hz", "--noise-scale", "--timestamp-jitter", "--drop-rows"):
        finite_option(name, getattr(args, name[2:].replace("-", "_")))
    if args.noise_scale < 0:
        raise ValueError("--noise-scale must be non-negative")
    effects = parse_effect_specs(args.effect)
    recording, truth = make_recording(
        effects, rng=np.random.default_rng(args.seed), duration_s=args.duration_s, sample_hz=args.rate_hz,
        model=args.model, noise=NoiseLevels().scaled(args.noise_scale), with_yaw_rate=not args.no_yaw_rate,
        with_lat_accel=not args.no_lat_accel, car=args.car, timestamp_jitter=args.timestamp_jitter,
        drop_fraction=args.drop_rows,
    )
    out = Path(args.out)
    truth["seed"] = args.seed
    write_recording(recording, out)
    write_text_atomic(out.with_name(out.stem + ".truth.json"),
                      json.dumps(strict(truth), indent=1, allow_nan=False) + "\n")
    print(f"wrote {out} ({recording.n} samples, {recording.duration_s:.0f} s, model {truth['model']}, "
          f"effects: {', '.join(truth['effects']) or 'none'})")
    return 0


def run(args) -> int:
    if args.command == "sim2real diagnose":
        return _run_diagnose(args)
    return _run_make_recording(args)
