"""``plm-highway sim2real diagnose``, ``sim2real make-recording`` (and the options of ``bench sim2real``).

Options only; the work is :func:`plm_highway.sim2real.workflow.diagnose_file`,
:func:`~plm_highway.sim2real.workflow.make_recording_file` and :mod:`plm_highway.sim2real.benchmark`,
whose signatures hold the defaults.
"""

from __future__ import annotations

import argparse
import math

from plm_highway.cli._common import (
    Command,
    add_overwrite,
    add_seed,
    bounded_float,
    bounded_int,
    defaults_of,
    static_defaults,
    static_names,
    strict_float,
)

GROUP_HELP = "find where a simulator and a recording disagree, and why"

# The recording bounds (rows, duration, sample rate) are checked when a recording is read, see
# plm_highway/sim2real/record/recording.py; these bound only what an option alone can get wrong.
MAX_SECONDS = 4 * 3600.0
# Shorter blocks interleave fitted and held-out samples closer than the dynamics remember (a delay, a
# steering lag): the held-out score would then measure interpolation, not prediction.
MIN_BLOCK_S = 1.0


def finite_nonzero(text: str) -> float:
    """An argparse type: a finite, non-zero number (a scale factor)."""

    value = strict_float(text, non_finite=True)
    if not math.isfinite(value) or value == 0:
        raise argparse.ArgumentTypeError(f"must be a finite, non-zero number, got {text}")
    return value


def configure_diagnose(parser) -> None:
    # Read from the library's source, not imported: the help page imports no scipy (tests/test_cli_help.py).
    defaults = static_defaults("plm_highway.sim2real.workflow", "diagnose_file")
    parser.add_argument("recording", help="recording CSV (sidecar <stem>.json read when present); format and "
                                          "bounds: plm_highway/sim2real/README.md")
    parser.add_argument("--json", dest="json_path", metavar="OUT.json", help="write the diagnosis as JSON")
    parser.add_argument("--report", dest="report_dir", metavar="DIR", help="write figures and summary.md into DIR")
    parser.add_argument("--sidecar", metavar="CAR.json", help="vehicle sidecar (default: <stem>.json)")
    parser.add_argument("--anchor-s", type=bounded_float(0.0, MAX_SECONDS, open_minimum=True),
                        default=defaults["anchor_s"],
                        help="re-anchor the replayed pose to the recording every this many seconds "
                             "(at least two samples, at most the recording)")
    parser.add_argument("--block-s", type=bounded_float(MIN_BLOCK_S, MAX_SECONDS),
                        default=defaults["block_s"],
                        help="length of the alternating cross-validation blocks (default: duration/16 in 2.5-8 s; "
                             f"at least {MIN_BLOCK_S:g} s, so held-out samples are not the neighbours of fitted "
                             "ones; the recording must hold at least four)")
    parser.add_argument("--split", choices=["blocks", "halves"], default=defaults["split"],
                        help="held-out data: 2-fold alternating blocks or fit the first half, score the second")
    parser.add_argument("--signal", choices=["auto", "yaw_rate", "heading"], default=defaults["signal"],
                        help="primary signal: the recorded yaw rate (auto, when present) or the heading's derivative")
    parser.add_argument("--steer-column", metavar="NAME",
                        help="read a simulator log instead: the steering command column (see read_sim_log)")
    parser.add_argument("--steer-scale", type=finite_nonzero, default=defaults["steer_scale"], metavar="SCALE",
                        help="with --steer-column: multiply the command by this to get radians "
                             "(0.2 for this project's env logs, whose steering is normalised)")
    parser.add_argument("--discovery", choices=["auto", "always", "never"], default=defaults["discovery"],
                        help="residual discovery of terms outside the library: auto (when the library leaves "
                             "structure or over 2%% of the error above the noise), always, never")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    add_overwrite(parser)


def run_diagnose(args) -> int:
    from plm_highway.sim2real.workflow import diagnose_file

    return diagnose_file(args.recording, json_path=args.json_path, report_dir=args.report_dir, sidecar=args.sidecar,
                         anchor_s=args.anchor_s, block_s=args.block_s, split=args.split, signal=args.signal,
                         steer_column=args.steer_column, steer_scale=args.steer_scale, discovery=args.discovery,
                         quiet=args.quiet, overwrite=args.overwrite)


def configure_make_recording(parser) -> None:
    from plm_highway.sim2real.physics.effects import EFFECTS
    from plm_highway.sim2real.physics.synth import CARS, OUTSIDE_EFFECTS
    from plm_highway.sim2real.workflow import make_recording_file

    defaults = defaults_of(make_recording_file)
    parser.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE[,KEY=VALUE...]]",
                        help="concealed effect, repeatable; VALUE sets its first parameter, KEY=VALUE others: "
                             + "; ".join(f"{n} ({', '.join(e.synth_defaults)})" for n, e in EFFECTS.items())
                             + "; outside the library: "
                             + "; ".join(f"{n} ({v[0]})" for n, v in OUTSIDE_EFFECTS.items()))
    parser.add_argument("--model", default=defaults["model"],
                        choices=["auto", "simulator", "kinematic", "single-track", "commonroad-st", "commonroad-mb"],
                        help="vehicle physics (auto: single-track when an effect needs tires, else kinematic)")
    parser.add_argument("--car", default=defaults["car"], choices=["auto", *CARS],
                        help="the car and its driving: sedan (the EKF paper's car, 10-30 m/s) or small (1:10 scale "
                             "F1TENTH car, 0.8-4 m/s); auto: the sedan, or the simulator's 5-m car for a "
                             "kinematic model")
    add_seed(parser, defaults["seed"])
    parser.add_argument("--out", required=True, metavar="REC.csv", help="output CSV (+ sidecar, + .truth.json)")
    parser.add_argument("--duration-s", type=bounded_float(10.0, 3600.0), default=defaults["duration_s"],
                        help="length of the recording [s] (10 s to 1 h)")
    parser.add_argument("--rate-hz", type=bounded_float(5.0, 1000.0), default=defaults["rate_hz"],
                        help="sample rate [Hz] (5 to 1000)")
    parser.add_argument("--noise-scale", type=bounded_float(0.0, 100.0), default=defaults["noise_scale"],
                        help="multiply every noise level (0 to 100)")
    parser.add_argument("--no-yaw-rate", dest="yaw_rate", action="store_false", help="leave out the yaw_rate column")
    parser.add_argument("--no-lat-accel", dest="lat_accel", action="store_false",
                        help="leave out the lat_accel column")
    parser.add_argument("--timestamp-jitter", type=bounded_float(0.0, 0.5), default=defaults["timestamp_jitter"],
                        metavar="FRACTION", help="sample times jitter uniformly by this fraction of the interval "
                                                 "(0-0.5)")
    parser.add_argument("--drop-rows", type=bounded_float(0.0, 0.5), default=defaults["drop_rows"],
                        metavar="FRACTION", help="drop this fraction of the rows at random (0-0.5)")
    add_overwrite(parser)


def run_make_recording(args) -> int:
    from plm_highway.sim2real.workflow import make_recording_file

    return make_recording_file(args.out, args.effect, model=args.model, car=args.car, seed=args.seed,
                               duration_s=args.duration_s, rate_hz=args.rate_hz, noise_scale=args.noise_scale,
                               yaw_rate=args.yaw_rate, lat_accel=args.lat_accel,
                               timestamp_jitter=args.timestamp_jitter, drop_rows=args.drop_rows,
                               overwrite=args.overwrite)


def configure_bench(parser) -> None:
    CASE_SETS = static_names("plm_highway.sim2real.benchmark", "CASE_SETS")  # from source: the help imports no scipy

    parser.add_argument("--cases", default="timing",
                        help=f"comma-separated: timing, match and/or case sets {', '.join(CASE_SETS)}")
    parser.add_argument("--seeds", type=bounded_int(1, 1000), default=3, help="seeds per case (match: 20 x this)")
    parser.add_argument("--duration-s", type=bounded_float(10.0, 3600.0), default=600.0,
                        help="timing: length of the recording [s]")
    parser.add_argument("--baseline-tree", metavar="DIR",
                        help="timing: also diagnose with the source tree DIR in a subprocess (both sides, one run)")
    parser.add_argument("--json", dest="json_path", metavar="OUT.json", help="also write the results as JSON")
    add_overwrite(parser)


def run_bench(args) -> int:
    from plm_highway.sim2real.benchmark import run_benchmarks

    return run_benchmarks([c.strip() for c in args.cases.split(",") if c.strip()], seeds=args.seeds,
                          duration_s=args.duration_s, baseline_tree=args.baseline_tree, json_path=args.json_path,
                          overwrite=args.overwrite, command=args.command_line)


COMMANDS = [
    Command("diagnose", "locate and explain a sim-vs-recording mismatch", configure_diagnose, run_diagnose),
    Command("make-recording", "synthesise a recording with concealed physics", configure_make_recording,
            run_make_recording),
]
