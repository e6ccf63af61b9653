"""``plm-highway calibrate``: the BM's degradation with latency under the paper's conditions, beside the paper's."""

from __future__ import annotations

from plm_highway.cli._common import (
    Command,
    add_overwrite,
    bounded_float,
    bounded_int,
    publish_figure_and_numbers,
    static_fields,
    static_names,
    static_value,
)


def configure(parser) -> None:
    from types import SimpleNamespace


    # Read from the library's source, not imported: the help page imports no torch (tests/test_cli_help.py).
    MAX_PROCESSING_DELAY_STEPS, MAX_STEERING_TIME_CONSTANT_S = (
        static_value("plm_highway.envs.config", name)
        for name in ("MAX_PROCESSING_DELAY_STEPS", "MAX_STEERING_TIME_CONSTANT_S"))
    DEFAULT_OUT = static_value("plm_highway.evaluation.calibration", "DEFAULT_OUT")
    READINGS = static_names("plm_highway.evaluation.calibration", "READINGS")
    CONDITION_NAMES, SPEED_LOGICS = (static_names("plm_highway.rollout.conditions", name)
                                     for name in ("CONDITION_NAMES", "SPEED_LOGICS"))
    FRICTION_RANGE = static_value("plm_highway.rollout.conditions", "FRICTION_RANGE")
    paper = SimpleNamespace(  # CONDITIONS["paper"]'s actuator, from the constants it is built of
        processing_delay_steps=static_value("plm_highway.rollout.conditions", "PAPER_PROCESSING_DELAY_STEPS"),
        steering_time_constant_s=static_value("plm_highway.rollout.conditions", "PAPER_STEERING_TIME_CONSTANT_S"))
    d = static_fields("plm_highway.evaluation.calibration", "CalibrationOptions")
    parser.add_argument("--out", default=str(DEFAULT_OUT),
                        help="figure to write (PNG); its numbers go beside it with the suffix .json")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default=d["conditions"],
                        help="paper: the paper's loop, pipeline, camera and the `paper` checkpoints")
    parser.add_argument("--speed-logic", choices=tuple(SPEED_LOGICS), default=d["speed_logic"],
                        help="constant: the conditions' speed (the paper's text); original-braking: the original run "
                             "scripts' full throttle up to 22 m/s, braking 1.7 s whenever |steering| > 0.25 in the "
                             "paper's unit (its acceleration and braking assumed)")
    parser.add_argument("--processing-delay-steps", type=bounded_int(0, MAX_PROCESSING_DELAY_STEPS),
                        help="policy steps between an action and the actuator, replacing the conditions' (paper: "
                             f"{paper.processing_delay_steps}, an assumption)")
    parser.add_argument("--steering-time-constant-s", type=bounded_float(0.0, MAX_STEERING_TIME_CONSTANT_S),
                        help="first-order steering actuator time constant [s], replacing the conditions' (paper: "
                             f"{paper.steering_time_constant_s:g}, an assumption)")
    parser.add_argument("--friction-coefficient", type=bounded_float(*FRICTION_RANGE),
                        help="give the car tires that saturate at this many g (the papers' Gazebo Prius: 0.9): the "
                             "kinematic car's geometry on stiff magic-formula tires, close to that car below the limit "
                             "(default: the conditions' kinematic bicycle, no limit)")
    parser.add_argument("--reading", choices=tuple(READINGS), default=d["reading"],
                        help="stated: the paper's latencies as it states them (0.15-0.30 s); loop-frames: as the "
                             "original counted them, 9/12/15/18 frames of its 30 Hz loop (0.30-0.60 s), the 2x "
                             "timebase ambiguity")
    parser.add_argument("--track", default=d["track"], help="train, test, unseen or a track JSON path")
    parser.add_argument("--checkpoints", help="directory with bm/ and tapm/ checkpoints (default: the conditions' "
                                              "shipped pair)")
    parser.add_argument("--seeds", default=str(d["seeds"]),
                        help="seeds: a count N (seeds 0..N-1) or a list a,b,c; at least two (the noise floor)")
    parser.add_argument("--max-steps", type=bounded_int(1, 10_000_000),
                        help="stop each run after this many policy steps (quick looks)")
    parser.add_argument("--workers", type=bounded_int(0, 256), default=d["workers"],
                        help="0: the runs batched in this process; N: on N processes (the same numbers)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--report-only", action="store_true",
                        help="render the figure and numbers at --out again from the per-seed values its .json holds "
                             "(every mean and interval computed again, the rules judged again); drive nothing, the "
                             "other options are ignored")
    add_overwrite(parser)


def run(args) -> int:
    from plm_highway.evaluation.calibration import (
        CALIBRATION_JSON,
        CalibrationOptions,
        bm_calibration,
        committed_calibration,
        summary_lines,
        write_calibration,
    )

    if args.report_only:  # in place, from the numbers committed beside the figure: no checkpoints, no runs
        from pathlib import Path

        result = committed_calibration(Path(args.out).with_suffix(".json"))
        figure_path, json_path = write_calibration(result, args.out, overwrite=True)
        for line in summary_lines(result):
            print(line)
        print(f"figure: {figure_path}\nnumbers: {json_path}")
        return 0

    options = CalibrationOptions(
        track=args.track, seeds=args.seeds, conditions=args.conditions, checkpoints=args.checkpoints,
        max_steps=args.max_steps, progress=not args.no_progress, workers=args.workers, speed_logic=args.speed_logic,
        processing_delay_steps=args.processing_delay_steps, steering_time_constant_s=args.steering_time_constant_s,
        friction_coefficient=args.friction_coefficient, reading=args.reading)

    def calibrate() -> dict:
        return bm_calibration(options)

    return publish_figure_and_numbers(args, calibrate, write_calibration, summary_lines, CALIBRATION_JSON)


COMMANDS = [Command("calibrate", "the BM's steering MAE vs latency under the paper's conditions beside the paper's "
                               "(the calibration figure and rules)", configure, run)]
