"""``plm-highway reproduce``: the paper's Tables 3-6 / A1-A6 and Figures 9-14 / A1-A9 on our simulator.

For each latency setting (default: constant 0.15, 0.20, 0.25, 0.30 s and the time-varying
``steps:0.0-0.35:1.0``) the Base Model drives the track with that latency (``baseline``) and
PLM-Net drives it with the same latency realisation (``mitigated``); both are compared with the
Base Model driving without latency (``reference``). The reference does not depend on the setting
(same track, seed and start; the runs are deterministic), so it is driven once per track.

Outputs (``--out``, default ``figures/reproduce``, or ``figures/reproduce/TRACK`` for another
``--track``), all written only after every run succeeded, through a temporary directory:

- ``report.md``: targets met / missed, then per setting the steering table (Tables 3, 5, A1, A3,
  A5 layout) and the trajectory table (Tables 4, 6, A2, A4, A6 layout), ours beside the paper's,
  with PLM-Net's reduction in % for both; the figures; the generalisation section (``--generalise``,
  default ``unseen`` when the track is ``test``); the latency sweep (``--sweep``); methods and notes.
- ``steering_tables.csv``, ``trajectory_tables.csv`` (long format: ours and paper per cell),
  ``targets.csv``, ``sweep.csv`` (with ``--sweep``) and ``results.json`` (everything, including each
  setting's ``plm-highway evaluate``-style result);
- ``<setting>_steering.png`` (Figures 9/12), ``<setting>_trajectories.png`` (10/13),
  ``<setting>_comparison.png`` (11/14), generalisation figures prefixed with the track name, and
  ``sweep.png``.

The checkpoints are trained on the ``train`` track; nothing here is tuned on the test track.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from tqdm import tqdm

from plm_highway.evaluation import paper_results as paper
from plm_highway.evaluation.closed_loop import drive
from plm_highway.evaluation.evaluate import check_inputs, compare_runs, run_steps
from plm_highway.evaluation.policies import checkpoint_pair, make_policy
from plm_highway.evaluation.trajectory import (
    METRIC_LABELS,
    METRICS,
    PARTS,
    RESAMPLE_SPACING_M,
    representative_segment,
)
from plm_highway.io import check_target, directory_kind, json_text, write_csv_into, write_output
from plm_highway.metrics.steering import ERROR_NAMES, reduction_pct
from plm_highway.road.track import TrackSpec, load_track

DEFAULT_SETTINGS = ("const:0.15", "const:0.2", "const:0.25", "const:0.3", "steps:0.0-0.35:1.0")
DEFAULT_OUT = Path("figures/reproduce")
DEFAULT_GENERALISATION = {"test": ("unseen",)}  # main track -> tracks of the generalisation section
RUNS = ("reference", "baseline", "mitigated")
RUN_ROW_LABELS = {"reference": "BM, no latency (ref)", "baseline": "BM, latency {label}",
                  "mitigated": "PLM-Net, latency {label}"}
PART_ROW_LABELS = {"full": "(a) Full track", "straight": "(b) Straight", "left": "(c) Left turn",
                   "right": "(d) Right turn"}
SHORT_METRIC = {"pcm": "PCM", "frechet_dist": "Frechet", "area_between_two_curves": "Area",
                "curve_length_measure": "Curve length", "dtw": "DTW", "dtsi": "DTSI"}


def _is_reproduce_report(path: Path) -> bool:
    """Report directories written before output markers existed: results.json recording this command."""
    try:
        command = json.loads((path / "results.json").read_text(encoding="utf-8")).get("command", "")
    except (OSError, ValueError, AttributeError):
        return False
    return (path / "report.md").is_file() and str(command).startswith("plm-highway reproduce")


REPRODUCE_REPORT = directory_kind("reproduce-report", "a plm-highway reproduction report directory",
                                  _is_reproduce_report)


# ---------------------------------------------------------------------------------------------
# settings, labels, file names
# ---------------------------------------------------------------------------------------------


def output_dir(out, track, track_name: str) -> Path:
    """``--out``, or ``figures/reproduce`` for the test track and ``figures/reproduce/NAME`` for others."""
    if out is not None:
        return Path(out)
    return DEFAULT_OUT if str(track) == "test" else DEFAULT_OUT / track_name


def split_settings(items) -> list[str]:
    specs: list[str] = []
    for item in items:
        for spec in str(item).split(","):
            if spec.strip() and spec.strip() not in specs:
                specs.append(spec.strip())
    if not specs:
        raise ValueError("--settings: no latency spec given")
    return specs


def paper_key(spec: str) -> str | None:
    """The key of ``spec`` in the paper's numbers (``const:0.20`` -> ``const:0.2``), or None."""
    match = re.fullmatch(r"const:([0-9.]+)", spec)
    if match:
        key = f"const:{float(match.group(1)):g}"
        return key if key in paper.SETTINGS else None
    return spec if spec in paper.SETTINGS else None


def setting_label(spec: str) -> str:
    key = paper_key(spec)
    if key is not None:
        return paper.SETTINGS[key]["label"]
    match = re.fullmatch(r"const:([0-9.]+)", spec)
    return f"{float(match.group(1)):.2f} s" if match else spec


def setting_tag(spec: str) -> str:
    """File-name part for a setting: ``0.20s``, ``time_varying`` or the spec made safe."""
    match = re.fullmatch(r"const:([0-9.]+)", spec)
    if match:
        return f"{float(match.group(1)):.2f}s"
    if spec == "steps:0.0-0.35:1.0":
        return "time_varying"
    return re.sub(r"[^A-Za-z0-9.]+", "_", spec).strip("_")


def is_constant(spec: str) -> bool:
    return spec.startswith("const:")


# ---------------------------------------------------------------------------------------------
# running
# ---------------------------------------------------------------------------------------------


class _Progress:
    def __init__(self, total: int, enabled: bool):
        self.bar = tqdm(total=total, desc="reproduce", unit="run", disable=not enabled, file=sys.stderr)

    def drive(self, name, policy, track, latency, seed, max_steps=None):
        self.bar.set_postfix_str(name, refresh=True)
        log = drive(name, policy, track, latency, seed, max_steps=max_steps)
        self.bar.update(1)
        return log

    def close(self) -> None:
        self.bar.close()


def run_track(track, specs: list[str], policies: dict, seed: int, max_steps: int | None, progress: _Progress) -> dict:
    """Drive the reference once and baseline + mitigated per setting; {spec: (result, logs)} + the reference."""
    track_spec = load_track(track)
    name = track_spec.name
    max_steps = run_steps(track, max_steps)
    reference = progress.drive(f"{name}: reference", policies["bm"], track, "const:0", seed, max_steps)
    out = {}
    for spec in specs:
        logs = {"reference": reference}
        logs["baseline"] = progress.drive(f"{name}: BM {spec}", policies["bm"], track, spec, seed, max_steps)
        logs["mitigated"] = progress.drive(f"{name}: PLM-Net {spec}", policies["plm"], track, spec, seed, max_steps)
        out[spec] = {"result": compare_runs(logs, track, spec, "plm", seed), "logs": logs}
    return {"track_spec": track_spec, "reference": reference, "settings": out}


def evaluate_targets(settings: dict) -> list[dict]:
    """Met / missed per target: the paper's MAE reductions and PLM-Net's full-track Frechet <= 1.5x reference's."""
    max_ratio = paper.TARGETS["mitigated_full_frechet_max_ratio_to_reference"]
    # PLM-Net's own steering error against the reference, at its best across the settings: a reduction
    # cannot exceed 1 - floor / (the BM's error), so a BM that barely degrades leaves little to remove.
    floor_mae = min(entry["result"]["steering"]["mitigated"]["mae"] for entry in settings.values())
    rows = []
    for spec, entry in settings.items():
        result = entry["result"]
        mitigated_run = result["runs"]["mitigated"]
        off_road = mitigated_run["left_road"]
        target = paper.TARGETS["mae_reduction_pct"].get(paper_key(spec) or "")
        ours = result["steering"]["mae_reduction_pct"]
        if target is not None:
            met = round(ours, 1) >= target and not off_road
            if met:
                how = f"ours {ours:.1f}% vs the paper's {target:.1f}%"
            elif off_road:
                how = (f"PLM-Net left the road ({100 * mitigated_run['completed_fraction']:.0f}% driven); "
                       f"over its run: ours {ours:.1f}%, paper {target:.1f}%")
            else:
                baseline_mae = result["steering"]["baseline"]["mae"]
                bound = 100.0 * (1.0 - floor_mae / baseline_mae) if baseline_mae > 0 else 0.0
                how = (f"missed by {target - ours:.1f} percentage points (ours {ours:.1f}%, paper {target:.1f}%). "
                       f"Why: the BM with this latency is only {baseline_mae:.4f} off the reference, and PLM-Net's "
                       f"own error floor (its lowest MAE across the settings) is {floor_mae:.4f}, so at most "
                       f"{bound:.0f}% could be removed")
            rows.append({"setting": spec, "target": f"steering MAE reduction >= {target:.1f}%",
                         "paper": target, "ours": ours, "met": met, "detail": how})
        frechet = result["trajectory"]["full"]
        ref_f, mit_f = frechet["reference"]["frechet_dist"], frechet["mitigated"]["frechet_dist"]
        if ref_f is None or mit_f is None or ref_f <= 0:
            rows.append({"setting": spec, "target": f"full-track Frechet <= {max_ratio}x reference",
                         "paper": max_ratio, "ours": None, "met": False, "detail": "not measurable"})
            continue
        ratio = mit_f / ref_f
        met = ratio <= max_ratio and not off_road
        detail = (f"PLM-Net {mit_f:.3f} m vs reference {ref_f:.3f} m: ratio {ratio:.2f}" if met else
                  f"missed: ratio {ratio:.2f} (PLM-Net {mit_f:.3f} m vs reference {ref_f:.3f} m), "
                  f"{mit_f - max_ratio * ref_f:.3f} m above {max_ratio}x. Why: PLM-Net's lateral offset RMS is "
                  f"{mitigated_run['lateral_offset_rms_m']:.3f} m against the reference's "
                  f"{result['runs']['reference']['lateral_offset_rms_m']:.3f} m; its worst moment sets the Frechet "
                  f"distance" + ("; PLM-Net left the road" if off_road else ""))
        rows.append({"setting": spec, "target": f"full-track Frechet <= {max_ratio}x reference",
                     "paper": max_ratio, "ours": ratio, "met": met, "detail": detail})
    return rows


def reproduce(track="test", settings=DEFAULT_SETTINGS, checkpoints=None, seed=0, max_steps=None, out=None,
              generalise=None, sweep=False, sweep_max=0.5, sweep_step=0.05, progress=True, command="",
              overwrite=False) -> dict:
    """Validate everything, drive every run, then write the outputs; returns the results dict."""
    from plm_highway.evaluation import sweep as sweep_module

    specs = split_settings(settings)
    main_spec, _ = check_inputs(track, specs[0], max_steps)
    for spec in specs[1:]:
        check_inputs(track, spec, max_steps)
    main_name = main_spec.name
    if generalise is None:
        generalise = DEFAULT_GENERALISATION.get(str(track), ())
    generalise = [g for g in dict.fromkeys(str(t) for t in generalise) if g != str(track)]
    for other in generalise:
        for spec in specs:
            check_inputs(other, spec, max_steps)
    latencies = sweep_module.sweep_latencies(sweep_max, sweep_step) if sweep else []
    bm_path, tapm_path = checkpoint_pair(checkpoints)
    policies = {"bm": make_policy("bm", checkpoints), "plm": make_policy("plm", checkpoints)}
    grid_max_s = round(float(policies["plm"].model_policy.model.delta_ref_s[-1]), 6)  # the TAPM's last latency
    out = output_dir(out, track, main_name)
    check_target(out, REPRODUCE_REPORT, overwrite=overwrite)

    n_runs = (1 + 2 * len(specs)) * (1 + len(generalise))
    if sweep:
        n_runs += len(sweep_module.planned_runs(latencies, sweep_module.LATENCY_BIASES_S, grid_max_s))
    bar = _Progress(n_runs, progress)
    try:
        main = run_track(track, specs, policies, seed, max_steps, bar)
        others = {}
        for other in generalise:
            run = run_track(other, specs, policies, seed, max_steps, bar)
            others[run["track_spec"].name] = run
        sweep_result = None
        if sweep:
            sweep_result = sweep_module.latency_sweep(
                track, policies["bm"], policies["plm"], main["reference"], seed, run_steps(track, max_steps), latencies,
                sweep_module.LATENCY_BIASES_S, grid_max_s, drive_fn=bar.drive)
    finally:
        bar.close()
    if progress:
        print(f"reproduce: all {n_runs} runs done; writing the tables, figures and report to {out}", file=sys.stderr)

    results = {
        "command": command or "plm-highway reproduce",
        "track": main_name, "seed": seed, "max_steps": max_steps, "settings_run": specs,
        "checkpoints": _checkpoint_info(bm_path, tapm_path),
        "resample_spacing_m": RESAMPLE_SPACING_M,
        "settings": {spec: entry["result"] for spec, entry in main["settings"].items()},
        "targets": evaluate_targets(main["settings"]),
        "generalisation": {name: {"settings": {s: e["result"] for s, e in run["settings"].items()},
                                  "targets": evaluate_targets(run["settings"])} for name, run in others.items()},
        "sweep": sweep_result,
    }
    write_outputs(results, main, others, main_spec, out, overwrite)
    return results


def _checkpoint_info(bm_path: Path, tapm_path: Path) -> dict:
    from plm_highway.models.checkpoints import KIND_BASE_MODEL, KIND_TAPM, read_description

    info = {}
    for key, path, kind in (("bm", bm_path, KIND_BASE_MODEL), ("tapm", tapm_path, KIND_TAPM)):
        description = read_description(path, kind)
        info[key] = {"path": _display_path(path), "fingerprint": description.get("fingerprint", "")[:16],
                     "preset": description.get("preset")}
    return info


def _display_path(path: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------


def write_outputs(results: dict, main: dict, others: dict, track_spec: TrackSpec, out: Path,
                  overwrite: bool = False) -> None:
    """Render every file into a staged directory, published as ``out`` in one step."""
    from plm_highway.evaluation import figures
    from plm_highway.evaluation.sweep import write_sweep_csv

    with write_output(out, REPRODUCE_REPORT, overwrite=overwrite) as tmp:
        figure_files: dict[str, dict[str, str]] = {}
        for spec, entry in main["settings"].items():
            figure_files[spec] = _setting_figures(figures, entry["logs"], track_spec, spec, tmp, prefix="",
                                                  track_name=results["track"])
        other_figures: dict[str, dict[str, str]] = {}
        for name, run in others.items():
            spec = list(run["settings"])[-1]  # the last setting (time-varying by default) stands for the rest
            other_figures[name] = _setting_figures(figures, run["settings"][spec]["logs"], run["track_spec"], spec,
                                                   tmp, prefix=re.sub(r"[^A-Za-z0-9.-]+", "_", name) + "_",
                                                   track_name=name)
            other_figures[name]["setting"] = spec
        if results["sweep"] is not None:
            figures.plot_sweep(results["sweep"], f"Latency sweep on the {results['track']} track: BM and PLM-Net",
                               tmp / "sweep.png")
            write_sweep_csv(results["sweep"], tmp / "sweep.csv")
        _write_tables_csv(results, tmp)
        (tmp / "results.json").write_text(json_text(results, REPRODUCE_REPORT, indent=1), encoding="utf-8")
        (tmp / "report.md").write_text(render_report(results, figure_files, other_figures, track_spec),
                                       encoding="utf-8")


def _setting_figures(figures, logs, track_spec, spec, directory: Path, prefix: str, track_name: str) -> dict[str, str]:
    label = setting_label(spec)
    key = paper_key(spec)
    numbers = paper.SETTINGS[key]["figures"] if key else {}
    tag = prefix + setting_tag(spec)

    def title(kind: str, what: str) -> str:
        ref = f"Figure {numbers[kind]} reproduction: " if kind in numbers and not prefix else ""
        return f"{ref}{what}, latency {label}, {track_name} track"

    files = {
        "steering": figures.plot_steering(logs, label, title("steering", "steering over time"),
                                          directory / f"{tag}_steering.png", latency_trace=not is_constant(spec)),
        "trajectories": figures.plot_trajectories_by_steering(
            logs, track_spec, label, title("trajectories_by_steering", "trajectories coloured by steering"),
            directory / f"{tag}_trajectories.png"),
        "comparison": figures.plot_trajectory_comparison(
            logs, track_spec, label, title("trajectory_comparison", "trajectories against the lane centre"),
            directory / f"{tag}_comparison.png"),
    }
    return {kind: path.name for kind, path in files.items()}


def _write_tables_csv(results: dict, directory: Path) -> None:
    steering_rows, trajectory_rows = [], []
    tracks = {results["track"]: results["settings"]}
    tracks.update({name: g["settings"] for name, g in results["generalisation"].items()})
    for track_name, settings in tracks.items():
        for spec, result in settings.items():
            key = paper_key(spec)
            tables = paper.SETTINGS[key]["tables"] if key else {"steering": "", "trajectory": ""}
            for row in steering_table_rows(result, key):
                steering_rows.append([track_name, tables["steering"], spec, *row])
            for row in trajectory_table_rows(result, key):
                trajectory_rows.append([track_name, tables["trajectory"], spec, *row])
    _write_csv(directory / "steering_tables.csv", ["track", "paper_table", "setting", "run", "metric", "ours", "paper"],
               steering_rows)
    _write_csv(directory / "trajectory_tables.csv",
               ["track", "paper_table", "setting", "part", "run", "metric", "ours", "paper"], trajectory_rows)
    target_rows = [[results["track"], t["setting"], t["target"], t["paper"], t["ours"], t["met"], t["detail"]]
                   for t in results["targets"]]
    for name, g in results["generalisation"].items():
        target_rows += [[name, t["setting"], t["target"], t["paper"], t["ours"], t["met"], t["detail"]]
                        for t in g["targets"]]
    _write_csv(directory / "targets.csv", ["track", "setting", "target", "paper", "ours", "met", "detail"], target_rows)


def _write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    write_csv_into(path, header, rows)


def steering_table_rows(result: dict, key: str | None) -> list[list]:
    """[run, metric, ours, paper] for baseline, mitigated and reduction_pct rows."""
    rows = []
    steering = result["steering"]
    for run in ("baseline", "mitigated"):
        theirs = paper.steering(key, run) if key else None
        for metric in ERROR_NAMES:
            rows.append([run, metric, steering[run][metric], theirs[metric] if theirs else None])
    for metric in ERROR_NAMES:
        theirs = _paper_steering_reduction(key, metric)
        rows.append(["reduction_pct", metric, steering[f"{metric}_reduction_pct"], theirs])
    return rows


def _paper_steering_reduction(key: str | None, metric: str) -> float | None:
    if key is None:
        return None
    base, mit = paper.steering(key, "baseline"), paper.steering(key, "mitigated")
    return reduction_pct(base[metric], mit[metric])


def trajectory_table_rows(result: dict, key: str | None) -> list[list]:
    """[part, run, metric, ours, paper] for the three runs and PLM-Net's reduction against the BM's."""
    rows = []
    for part in PARTS:
        ours_part = result["trajectory"][part]
        for run in RUNS:
            theirs = paper.trajectory(key, part, run) if key else None
            for metric in METRICS:
                rows.append([part, run, metric, ours_part[run][metric], theirs[metric] if theirs else None])
        for metric in METRICS:
            rows.append([part, "reduction_pct", metric, _reduction(ours_part, metric),
                         _paper_trajectory_reduction(key, part, metric)])
    return rows


def _reduction(part_metrics: dict, metric: str) -> float | None:
    base, mit = part_metrics["baseline"][metric], part_metrics["mitigated"][metric]
    return None if base is None or mit is None or base == 0 else reduction_pct(base, mit)


def _paper_trajectory_reduction(key: str | None, part: str, metric: str) -> float | None:
    if key is None:
        return None
    base, mit = paper.trajectory(key, part, "baseline"), paper.trajectory(key, part, "mitigated")
    return reduction_pct(base[metric], mit[metric])


# ---------------------------------------------------------------------------------------------
# the report
# ---------------------------------------------------------------------------------------------


def _num(value, digits: int = 4) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    magnitude = abs(value)
    if magnitude >= 1000:
        return f"{value:,.1f}"
    if magnitude >= 10:
        return f"{value:.2f}"
    if magnitude >= 1:
        return f"{value:.3f}"
    return f"{value:.{digits}f}"


def _pct(value) -> str:
    return "—" if value is None else f"{value:.1f}%"


def steering_table_markdown(result: dict, spec: str, with_paper: bool = True) -> list[str]:
    key = paper_key(spec) if with_paper else None
    label = setting_label(spec)
    steering = result["steering"]
    head = "| BM, no latency vs. |" + "".join(f" {m.upper()} ours | {m.upper()} paper |" for m in ERROR_NAMES)
    lines = [head, "|---" * (1 + 2 * len(ERROR_NAMES)) + "|"]
    for run in ("baseline", "mitigated"):
        theirs = paper.steering(key, run) if key else None
        cells = "".join(f" {_num(steering[run][m])} | {_num(theirs[m]) if theirs else '—'} |" for m in ERROR_NAMES)
        off = " (left the road)" if result["runs"][run]["left_road"] else ""
        lines.append(f"| {RUN_ROW_LABELS[run].format(label=label)}{off} |{cells}")
    cells = "".join(f" **{_pct(steering[f'{m}_reduction_pct'])}** | {_pct(_paper_steering_reduction(key, m))} |"
                    for m in ERROR_NAMES)
    lines.append(f"| PLM-Net's reduction vs BM |{cells}")
    return lines


def trajectory_table_markdown(result: dict, spec: str, with_paper: bool = True) -> list[str]:
    """Rows (part, run) and, per metric, ours beside the paper's (``with_paper``) or ours alone."""
    key = paper_key(spec) if with_paper else None
    label = setting_label(spec)

    def pair(ours: str, theirs: str) -> str:
        return f" {ours} | {theirs} |" if with_paper else f" {ours} |"

    head = "| part | driving model |" + "".join(
        f" {SHORT_METRIC[m]} ours | paper |" if with_paper else f" {SHORT_METRIC[m]} |" for m in METRICS)
    lines = [head, "|---" * (2 + (2 if with_paper else 1) * len(METRICS)) + "|"]
    for part in PARTS:
        ours_part = result["trajectory"][part]
        for run in RUNS:
            theirs = paper.trajectory(key, part, run) if key else None
            cells = "".join(pair(_num(ours_part[run][m]), _num(theirs[m]) if theirs else "—") for m in METRICS)
            lines.append(f"| {PART_ROW_LABELS[part]} | {RUN_ROW_LABELS[run].format(label=label)} |{cells}")
        cells = "".join(pair(f"*{_pct(_reduction(ours_part, m))}*", f"*{_pct(_paper_trajectory_reduction(key, part, m))}*")
                        for m in METRICS)
        lines.append(f"| {PART_ROW_LABELS[part]} | *PLM-Net's reduction vs BM* |{cells}")
    return lines


def _targets_markdown(targets: list[dict]) -> list[str]:
    lines = ["| setting | target | met? | detail |", "|---|---|---|---|"]
    for t in targets:
        lines.append(f"| {setting_label(t['setting'])} | {t['target']} | {'**met**' if t['met'] else '**missed**'} | "
                     f"{t['detail']} |")
    met = sum(t["met"] for t in targets)
    lines += ["", f"{met} of {len(targets)} targets met."]
    return lines


def _runs_markdown(result: dict) -> str:
    parts = []
    for run in RUNS:
        summary = result["runs"][run]
        status = "left the road" if summary["left_road"] else f"{100 * summary['completed_fraction']:.0f}% of the track"
        extra = (f", {summary['latency_clamped_steps']} steps above the TAPM grid"
                 if run == "mitigated" and summary.get("latency_clamped_steps") else "")
        parts.append(f"{run}: {summary['steps']} steps, {status}, offset RMS {summary['lateral_offset_rms_m']:.3f} m"
                     f"{extra}")
    return "Runs: " + "; ".join(parts) + "."


def render_report(results: dict, figure_files: dict, other_figures: dict, track_spec: TrackSpec) -> str:
    track = results["track"]
    ck = results["checkpoints"]
    lines = [
        f"# Reproducing PLM-Net on the `{track}` track",
        "",
        f"Command: `{results['command']}`. Seed {results['seed']}"
        + (f", at most {results['max_steps']} steps per run (a shortened run: numbers are not comparable with the "
           "paper's)" if results["max_steps"] else ", full track")
        + f". Checkpoints: BM `{ck['bm']['path']}` ({ck['bm']['fingerprint']}), TAPM `{ck['tapm']['path']}` "
          f"({ck['tapm']['fingerprint']}), trained on the `train` track; nothing was tuned on the test track.",
        "",
        ("Runs: the Base Model without latency (reference, blue), the Base Model with latency (baseline, green) and "
        "PLM-Net with the same latency realisation (red), as in the paper. Our simulator, camera, driver and models "
        "differ from the paper's (OSCAR/Gazebo, a human driver, a 160x160 BM), so the numbers are compared for "
        "their direction and size, not for equality; the paper's targets below are its MAE reductions."),
        "",
    ]
    if track != "test":
        lines += [(f"The paper's numbers are for its own test track; on the `{track}` track they are shown for "
                  "orientation only."), ""]
    lines += ["## Targets", ""] + _targets_markdown(results["targets"]) + [""]
    lines += ["## Summary", "", ("| setting | BM MAE | PLM-Net MAE | MAE reduction (ours / paper) | full-track Frechet: "
              "reference / BM / PLM-Net [m] | left the road |"), "|---|---|---|---|---|---|"]
    for spec, result in results["settings"].items():
        key = paper_key(spec)
        paper_pct = _pct(paper.TARGETS["mae_reduction_pct"].get(key or "")) if key else "—"
        lines.append(_summary_row(spec, result, [paper_pct]))
    lines.append("")
    for spec, result in results["settings"].items():
        key = paper_key(spec)
        label = setting_label(spec)
        tables = paper.SETTINGS[key]["tables"] if key else None
        numbers = paper.SETTINGS[key]["figures"] if key else None
        steering_name = f"Table {tables['steering']}" if tables else "Steering table"
        trajectory_name = f"Table {tables['trajectory']}" if tables else "Trajectory table"
        heading = f"Latency {label}" if is_constant(spec) else label[0].upper() + label[1:]
        lines += [f"## {heading} (`{spec}`)", "", _runs_markdown(result), "",
                  f"### {steering_name}: steering angle similarity, latency {label}", ""]
        lines += steering_table_markdown(result, spec) + [""]
        lines += [f"### {trajectory_name}: trajectory similarity against the lane centre, latency {label}", "",
                  ("Straight / left / right: mean over every segment of that kind (see Methods). "
                  "Italic rows: PLM-Net's reduction against the BM with latency (negative: PLM-Net is worse)."), ""]
        lines += trajectory_table_markdown(result, spec) + [""]
        files = figure_files[spec]
        for kind, caption in (("steering", "steering over time"),
                              ("trajectories_by_steering", "trajectories coloured by steering"),
                              ("trajectory_comparison", "trajectories against the lane centre")):
            file_key = {"trajectories_by_steering": "trajectories", "trajectory_comparison": "comparison"}.get(kind, kind)
            number = f"Figure {numbers[kind]}: " if numbers else ""
            lines += [f"![{number}{caption}, latency {label}]({files[file_key]})", ""]
    lines += _generalisation_markdown(results, other_figures)
    if results["sweep"] is not None:
        from plm_highway.evaluation.sweep import sweep_markdown

        lines += ["## Beyond the paper: latency sweep and a wrong latency estimate", "",
                  (f"Constant latency from 0 to {max(results['sweep']['latencies_s']):.2f} s on the `{track}` track. "
                  "Steering MAE is against the BM without latency, step by step over each run's length; offset RMS is "
                  "from the lane centre. Beyond the TAPM grid "
                  f"({results['sweep']['tapm_grid_max_s']:.2f} s) PLM-Net uses its last head."), ""]
        lines += sweep_markdown(results["sweep"]) + ["", "![latency sweep](sweep.png)", ""]
    lines += _methods_markdown(track_spec)
    return "\n".join(lines) + "\n"


def _summary_row(spec: str, result: dict, compared_pct: list[str], extra_cells: list[str] = ()) -> str:
    """One summary line: BM and PLM-Net MAE, our reduction / the compared one, Frechet per run, extras, off-road runs."""
    frechet = result["trajectory"]["full"]
    off = [run for run in RUNS if result["runs"][run]["left_road"]]
    cells = [setting_label(spec), _num(result["steering"]["baseline"]["mae"]), _num(result["steering"]["mitigated"]["mae"]),
             " / ".join([_pct(result["steering"]["mae_reduction_pct"]), *compared_pct]),
             " / ".join(_num(frechet[run]["frechet_dist"], 3) for run in RUNS), *extra_cells, ", ".join(off) or "none"]
    return "| " + " | ".join(cells) + " |"


def _generalisation_markdown(results: dict, other_figures: dict) -> list[str]:
    if not results["generalisation"]:
        return []
    lines = ["## Generalisation: tracks the models never saw in training", ""]
    for name, g in results["generalisation"].items():
        lines += [f"### The `{name}` track", "",
                  (f"The same settings and checkpoints on the `{name}` track (no paper numbers exist for it; the "
                  f"`{results['track']}` track's results are beside ours for comparison)."), ""]
        lines += _targets_markdown(g["targets"]) + [""]
        lines += [(f"| setting | BM MAE | PLM-Net MAE | MAE reduction ({name} / {results['track']}) | full-track Frechet "
                  f"reference / BM / PLM-Net [m] | PLM-Net / reference Frechet ({name} / {results['track']}) | "
                  "left the road |"), "|---|---|---|---|---|---|---|"]
        for spec, result in g["settings"].items():
            main = results["settings"].get(spec)
            main_pct = _pct(main["steering"]["mae_reduction_pct"]) if main else "—"
            ratios = f"{_ratio(result['trajectory']['full'])} / {_ratio(main['trajectory']['full']) if main else '—'}"
            lines.append(_summary_row(spec, result, [main_pct], extra_cells=[ratios]))
        lines.append("")
        for spec, result in g["settings"].items():
            lines += [f"#### `{name}` track, latency {setting_label(spec)}: trajectory similarity", ""]
            lines += trajectory_table_markdown(result, spec, with_paper=False) + [""]
        files = other_figures.get(name)
        if files:
            label = setting_label(files["setting"])
            lines += [f"![{name} track: steering over time, latency {label}]({files['steering']})", "",
                      f"![{name} track: trajectories coloured by steering, latency {label}]({files['trajectories']})",
                      "", (f"![{name} track: trajectories against the lane centre, latency {label}]"
                          f"({files['comparison']})"), ""]
    return lines


def _ratio(frechet: dict) -> str:
    ref, mit = frechet["reference"]["frechet_dist"], frechet["mitigated"]["frechet_dist"]
    return "—" if ref in (None, 0) or mit is None else f"{mit / ref:.2f}"


def _methods_markdown(track_spec: TrackSpec) -> list[str]:
    kinds = {kind: [i for i, s in enumerate(track_spec.segments) if s.direction == kind]
             for kind in ("straight", "left", "right")}
    lines = [
        "## Methods", "",
        ("- **Steering** (Tables 3, 5, A1, A3, A5): MAE, MSE and RMSE of each delayed run's normalised steering "
        "against the reference run's, step by step (20 Hz; a run that left the road is compared over its length). "
        "Reduction = 100 (1 - PLM-Net's error / BM's error); the paper's reductions are computed from its tables "
        "the same way."),
        "- **Trajectories** (Tables 4, 6, A2, A4, A6): each run's x, y path against the lane centre (the starting "
        "lane's centre line: the reference line offset by that lane's offset; the middle lane here, i.e. the "
        "reference line), over the stretch the run covered. Both curves are resampled every "
        f"{RESAMPLE_SPACING_M} m of arc length first (PCM, DTW and curve length depend on the number of points). "
        "Metrics: " + ", ".join(METRIC_LABELS[m] for m in METRICS) + " (the fast drop-ins for similaritymeasures "
        "in `plm_highway.metrics`; DTW is the distance). DTSI is the reconstruction EMDC = 0.5 MMDC + 0.5 MDDC of "
        "the run's lateral offset and time (see `plm_highway.metrics.lane`), not the authors' code.",
        "- **Parts**: full = the whole run; straight / left / right = every segment of that kind in the track "
        "spec, each measured separately (the run's points whose arc length lies in it, against the lane centre over "
        "the same stretch), then averaged. On this track: "
        + "; ".join(f"{kind} segments {idx}" for kind, idx in kinds.items())
        + ". The paper shows one segment per kind; averaging avoids an arbitrary pick (the first straight is a "
          "run-in from a centred start). The figures show one representative segment per kind (the first that "
          "does not start the track: "
        + ", ".join(f"{kind} {representative_segment(track_spec, kind)}" for kind in kinds) + ").",
        ("- **Frame**: the curve length measure divides by the lane centre's mean x and y, so coordinates are "
        "shifted to put the road's bounding box corner at (0, 0). PCM normalises by the lane centre's x and y "
        "ranges: it is undefined (—) on a stretch parallel to an axis (our first straight) and very large on a "
        "nearly axis-parallel one, which is also why the paper's straight-road PCM values are in the hundreds."),
        ("- **Runs**: 20 Hz policy and simulation, 16.7 m/s; the time-varying profile redraws a latency uniformly "
        "in [0, 0.35] s every second from the seed, identically for the BM and PLM-Net; PLM-Net is told the "
        "measured age of each frame."),
        "",
        "### Notes on the paper's numbers", "",
    ]
    lines += [f"- {note}" for note in paper.NOTES]
    return lines + [""]
