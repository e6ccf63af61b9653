"""Plug-in mitigations judged on the population's committed pairs, beside the BM, PLM-Net and the EKF lane keeper.

Two parts, each driven once and committed as a record of its own under ``OUT/parts/`` (so the study grows and
resumes as the population does):

- ``pair-NN`` for every committed population pair (the paper recipe and conditions): the pair's checkpoints, read
  from the population's work directory and refused unless their weights hash to what the pair's record holds,
  drive each design and the EKF lane keeper under every setting and simulator seed of the population; the BM's and
  PLM-Net's rows are the population's own (same pair, setting and seed), and the reference (the BM without latency)
  is driven again to judge the new runs against and checked to equal the population's;
- ``shipped``: the shipped default pair under the ideal conditions, every policy driven here.

Each part also holds the designs' posed feedback gains (:func:`posed_gains`): the car posed at a lateral offset or
heading error on a straight when the frame was captured, then driven straight on at its speed for the latency, and
the steering each design issues; PLM-Net's are the population's.

A part is reused only while everything it was made from is unchanged (the population record, the checkpoints'
hashes, the settings, seeds, designs and the source of the mitigation code); otherwise it is driven again.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import plm_highway.mitigation as package
from plm_highway.errors import BadInput
from plm_highway.evaluation.outcomes import run_outcomes
from plm_highway.evaluation.protocol import constant_latency_s
from plm_highway.evaluation.reproduce import conditions_named
from plm_highway.io import JSON_MARKER_KEY, directory_kind, file_kind, json_text, write_csv_into, write_output
from plm_highway.io.bounded import JsonLimits, load_json
from plm_highway.io.digests import kit_version, source_sha256
from plm_highway.mitigation import make_mitigation
from plm_highway.mitigation.posing import gains_from_answers, posed_frames
from plm_highway.population.analysis import spread
from plm_highway.population.ledger import LEDGER_DIR, file_sha256, read_record, sealed
from plm_highway.road.track import resolve_track
from plm_highway.rollout.cells import Cell, advancing, progress_bar, run_cells, runs_under
from plm_highway.rollout.conditions import baseline_latency
from plm_highway.rollout.policies import MITIGATED_POLICIES, make_policy, single_threaded_inference

DESIGNS = ("bm-warp", "bm-smith")  # the plug-in mitigations judged (plm_highway.mitigation)
COMPARED = ("bm", "plm", "ekf")  # what they are judged beside
POLICIES = (*COMPARED, *DESIGNS)
POLICY_TITLES = {"bm": "BM (no mitigation)", "plm": "PLM-Net", "ekf": "EKF lane keeper (delay-compensated)",
                 "bm-warp": "BM + view warp", "bm-smith": "BM + Smith correction"}
OUTCOMES = ("steering_mae_paper", "offset_rms_m", "offset_max_m", "frechet_m")
PART_RECORD = file_kind("mitigation-part", "a mitigation study's part record")
MITIGATION_REPORT = directory_kind("mitigation-report", "a plm-highway mitigation report directory")
PART_FORMAT = "plm_highway.mitigation.part/1"
PARTS_DIR = "parts"
AIM_SETTINGS = ("const:0.25", "const:0.3", "steps:0.0-0.35:1.0")  # on the road in every run here
AIM_EKF_RATIO = 1.2  # lane-offset RMS within this factor of the EKF lane keeper's
# The settings the designs are driven under: the aim's, where PLM-Net leaves the road. A population pair's runs at
# 0.15 s and 0.20 s (where PLM-Net and the BM stay on it) are not driven again for the designs: a part of 5 seeds
# costs about 20 CPU-minutes at these three settings (the EKF lane keeper's per-frame filter runs in Python).
JUDGED_SETTINGS = AIM_SETTINGS
SHIPPED_SETTINGS = AIM_SETTINGS
MAX_PART_BYTES = 16 << 20


@dataclass(frozen=True)
class Part:
    """One part of the study: ``name`` (``pair-NN`` or ``shipped``), its conditions, track, settings and seeds, the
    checkpoint directory (None: the shipped pair) and, for a pair, its population record."""

    name: str
    conditions: str
    track: str
    settings: tuple[str, ...]
    seeds: tuple[int, ...]
    checkpoints: Path | None
    record: dict | None = None
    max_steps: int | None = None  # quick runs only (tests): every run stops after this many steps

    def made_from(self) -> dict:
        return {"conditions": self.conditions, "track": self.track, "settings": list(self.settings),
                "seeds": list(self.seeds), "designs": list(DESIGNS), "max_steps": self.max_steps,
                "population_record_sha256": None if self.record is None else self.record["record_sha256"],
                "checkpoints": None if self.record is None else self.record["checkpoints"],
                "code_sha256": code_sha256(), "kit_version": kit_version()}


def code_sha256() -> str:
    """The digest of the mitigation code's source (a changed design makes its parts stale)."""
    return source_sha256(package)


def population_parts(population_out: Path, work: Path, pairs: int | None = None) -> list[Part]:
    """The committed population pairs under ``population_out`` (the first ``pairs`` of them), each with its
    checkpoints in ``work``, verified by hash."""
    paths = sorted((Path(population_out) / LEDGER_DIR).glob("pair-*.json"))
    if not paths:
        raise BadInput(f"{population_out}: no committed population pairs ({LEDGER_DIR}/pair-NN.json); run "
                       "'plm-highway population' first")
    parts = []
    for path in paths[:pairs]:
        record = read_record(path)
        pair = int(record["pair"])
        directory = Path(work) / "pairs" / f"pair-{pair:02d}"
        checked_checkpoints(directory, record, path)
        made = record["made_from"]
        settings = tuple(s for s in made["settings"] if s in JUDGED_SETTINGS)
        parts.append(Part(f"pair-{pair:02d}", made["conditions"], made["track"], settings,
                          tuple(made["sim_seeds"]), directory, record))
    return parts


def checked_checkpoints(directory: Path, record: dict, record_path: Path) -> None:
    """Refuse ``directory`` unless its BM and TAPM weights are those ``record`` (a population pair) was made with."""
    files = {}
    for model in ("bm", "tapm"):
        path = directory / model / "model.pt"
        if not path.is_file():
            raise BadInput(f"{path}: missing; pair {record['pair']}'s checkpoints are made by 'plm-highway population' "
                           f"into its work directory (give it with --work)")
        files[model] = {"model.pt": path.read_bytes()}
    found = file_sha256(files)
    differ = [name for name, digest in record["checkpoints"].items() if found.get(name) != digest]
    if differ:
        raise BadInput(f"{directory}: its {', '.join(differ)} are not the weights pair {record['pair']} was made with "
                       f"({record_path} holds other hashes); give the --work of that population")


def shipped_part(seeds: Sequence[int], settings: Sequence[str] = SHIPPED_SETTINGS, max_steps: int | None = None
                 ) -> Part:
    return Part("shipped", "ideal", "test", tuple(settings), tuple(seeds), None, max_steps=max_steps)


# ---------------------------------------------------------------------------------------------------------------
# driving one part
# ---------------------------------------------------------------------------------------------------------------


def drive_part(part: Part, backend=None, batch_size: int = 16, progress: bool = True) -> dict:
    """Every run of ``part`` not taken from the population; the part's record (rows, gains, checks)."""
    conditions = conditions_named(part.conditions)
    track_spec = resolve_track(part.track)
    driven = DESIGNS + ("ekf",) if part.record is not None else POLICIES
    cells = []
    for seed in part.seeds:
        cells.append(Cell("reference", "bm", "const:0", seed, f"{part.name}: reference, seed {seed}"))
        for setting in part.settings:
            for policy in driven:
                latency = baseline_latency(setting, conditions) if policy == "bm" else setting
                cells.append(Cell(policy, policy, latency, seed, f"{part.name}: {policy} {setting}, seed {seed}",
                                  setting))
    bar = progress_bar(len(cells), progress, f"mitigations: {part.name}")
    with single_threaded_inference():
        logs = run_cells(runs_under(cells, track_spec, conditions, None, part.max_steps), part.checkpoints,
                         preset=conditions.checkpoint_preset, batch_size=batch_size, backend=backend,
                         on_done=advancing(bar))
    bar.close()
    references = {cell.seed: log for cell, log in zip(cells, logs) if cell.role == "reference"}
    rows = []
    for cell, log in zip(cells, logs):
        outcomes = run_outcomes(log, references[cell.seed], track_spec, conditions.max_steering_rad)
        rows.append({"part": part.name, "seed": cell.seed, "policy": "reference" if cell.role == "reference"
                     else cell.policy, "setting": "const:0" if cell.role == "reference" else cell.setting,
                     **{key: outcomes[key] for key in (*OUTCOMES, "left_road")}})
    record = {"format": PART_FORMAT, "part": part.name, "made_from": part.made_from(), "rows": rows,
              "gains": posed_gains(part, conditions)}
    if part.record is not None:
        record["rows"] += population_rows(part)
        record["reference_check"] = reference_check(part, rows)
    return record


POPULATION_ROLES = {"baseline": "bm", "mitigated": "plm"}


def population_rows(part: Part) -> list[dict]:
    """The BM's and PLM-Net's rows of the population's record for ``part``'s settings and seeds."""
    rows = []
    for row in part.record["runs"]:
        if row.get("remedy") or row["role"] not in POPULATION_ROLES or row["setting"] not in part.settings:
            continue
        rows.append({"part": part.name, "seed": row["seed"], "policy": POPULATION_ROLES[row["role"]],
                     "setting": row["setting"], **{key: row[key] for key in (*OUTCOMES, "left_road")}})
    return rows


def reference_check(part: Part, rows: list[dict]) -> dict:
    """Whether the reference driven here is the population's (same lane-offset RMS per seed, to 1e-9 m)."""
    ours = {r["seed"]: r["offset_rms_m"] for r in rows if r["policy"] == "reference"}
    theirs = {r["seed"]: r["offset_rms_m"] for r in part.record["runs"] if r["role"] == "reference"
              and not r.get("remedy")}
    worst = max(abs(ours[s] - theirs[s]) for s in ours if s in theirs) if set(ours) & set(theirs) else math.nan
    return {"seeds": sorted(set(ours) & set(theirs)), "max_offset_rms_difference_m": worst,
            "same": bool(math.isfinite(worst) and worst <= 1e-9)}


def posed_gains(part: Part, conditions) -> dict:
    """Each design's posed feedback gains at each constant latency of ``part`` (module docstring), the BM's (no
    latency) and, for the shipped part, PLM-Net's; ``{"bm": {...}, "bm-warp@0.25": {...}, ...}``."""
    bm = make_policy("bm", part.checkpoints, preset=conditions.checkpoint_preset).model_policy
    plm = None if part.record is not None else make_policy("plm", None, preset=conditions.checkpoint_preset).model_policy
    latencies = [lat for lat in (constant_latency_s(s) for s in part.settings) if lat]
    frames = posed_frames(conditions.env_config(), part.track, conditions.camera)
    step_s = 1.0 / conditions.policy_frequency_hz
    answers: dict[str, dict[str, list[float]]] = {}

    def answer(who: str, sweep: str, value: float) -> None:
        answers.setdefault(who, {}).setdefault(sweep, []).append(float(value))

    for sweep, frame, info in frames:
        speed_mps = float(info["speed_mps"])
        answer("bm", sweep, bm(frame, speed_mps, 0.0))
        for latency_s in latencies:
            if plm is not None:
                answer(f"plm@{latency_s:g}", sweep, plm(frame, speed_mps, latency_s))
            steps = round(latency_s / step_s)
            for design in DESIGNS:
                mitigation = make_mitigation(MITIGATED_POLICIES[design], conditions.camera, 0, bm,
                                             conditions.env_config())
                mitigation.reset()
                # the car drove straight on at its speed since the frame: the sensors read that, step by step
                for k in range(steps + 1):
                    state = {"time_s": k * step_s, "speed_mps": speed_mps, "yaw_rate_radps": 0.0}
                    model_frame = mitigation.model_input(frame, state, k * step_s)
                steering = mitigation.output(bm(model_frame, speed_mps, 0.0), state)
                answer(f"{design}@{latency_s:g}", sweep, steering)
    return {who: gains_from_answers(sweeps) for who, sweeps in answers.items()}


# ---------------------------------------------------------------------------------------------------------------
# parts on disk
# ---------------------------------------------------------------------------------------------------------------


def part_path(out: Path, name: str) -> Path:
    return Path(out) / PARTS_DIR / f"{name}.json"


def read_part(out: Path, part: Part) -> dict | None:
    """The committed record of ``part`` under ``out`` if it was made from what ``part`` is made from now."""
    path = part_path(out, part.name)
    if not path.is_file():
        return None
    data = _read_sealed_part(path)
    stored = json_roundtrip(data["made_from"])
    return data if stored == json_roundtrip(part.made_from()) else None


def committed_parts(out: Path) -> list[dict]:
    """Every part record committed under ``out`` (pairs in order, then the shipped pair), each checked unedited."""
    paths = sorted((Path(out) / PARTS_DIR).glob("*.json"), key=lambda p: (p.stem == "shipped", p.stem))
    if not paths:
        raise BadInput(f"{out}: no committed mitigation parts ({PARTS_DIR}/*.json); run 'plm-highway mitigations'")
    return [_read_sealed_part(path) for path in paths]


def _read_sealed_part(path: Path) -> dict:
    data = load_json(path, JsonLimits(max_bytes=MAX_PART_BYTES), what=PART_RECORD.describe)
    if not isinstance(data, dict) or data.get(JSON_MARKER_KEY) != PART_RECORD.name or data.get("format") != PART_FORMAT:
        raise BadInput(f"{path}: not {PART_RECORD.describe}")
    data.pop(JSON_MARKER_KEY)
    if sealed({k: v for k, v in data.items() if k != "record_sha256"}) != data:
        raise BadInput(f"{path}: its contents were changed after plm-highway wrote it (record_sha256 does not match); "
                       "restore it from git, or remove it to have the part driven again")
    return data


def json_roundtrip(value):
    """``value`` as its JSON file reads back (tuples as lists, keys as strings)."""
    return json.loads(json_text(value))


def write_part(out: Path, record: dict) -> Path:
    relative = f"{PARTS_DIR}/{record['part']}.json"
    with write_output(out, MITIGATION_REPORT, update=[relative]) as staged:
        (staged / PARTS_DIR).mkdir()
        (staged / relative).write_text(json_text(sealed(record), PART_RECORD), encoding="utf-8")
    return Path(out) / relative


# ---------------------------------------------------------------------------------------------------------------
# analysis
# ---------------------------------------------------------------------------------------------------------------


def _unit_values(rows: list[dict], units: list[tuple], policy: str, setting: str, key: str) -> list[float]:
    """One value per unit (``(part, None)``: the part's mean over seeds; ``(part, seed)``: that run's); NaN where the
    unit has none."""
    found = []
    for part, seed in units:
        numbers = [float(r[key]) for r in rows if r["part"] == part and (seed is None or r["seed"] == seed)
                   and r["policy"] == policy and r["setting"] == setting
                   and r[key] is not None and math.isfinite(float(r[key]))]
        found.append(float(np.mean(numbers)) if numbers else math.nan)
    return found


def summarise(records: list[dict]) -> dict:
    """Per group (``population``: the pairs, one value per pair = its mean over seeds; ``shipped``: one value per
    seed), setting and policy: each outcome's mean and 95% interval, runs that left the road, and the designs'
    paired differences against PLM-Net and ratios to the EKF lane keeper's lane-offset RMS."""
    groups = {"population": [r for r in records if r["part"].startswith("pair-")],
              "shipped": [r for r in records if r["part"] == "shipped"]}
    out: dict = {}
    for group, parts in groups.items():
        if not parts:
            continue
        rows = [row for record in parts for row in record["rows"]]
        settings = list(dict.fromkeys(r["setting"] for r in rows if r["policy"] != "reference"))
        units = ([(record["part"], None) for record in parts] if group == "population"
                 else [("shipped", seed) for seed in sorted({r["seed"] for r in rows})])

        def values(policy: str, setting: str, key: str, rows=rows, units=units) -> list[float]:
            return _unit_values(rows, units, policy, setting, key)

        entry: dict = {"units": len(units), "unit": "pair" if group == "population" else "seed", "settings": {}}
        for setting in settings:
            per_policy = {}
            for policy in POLICIES:
                chosen = [r for r in rows if r["policy"] == policy and r["setting"] == setting]
                if not chosen:
                    continue
                summary = {"runs": len(chosen), "left_road": sum(bool(r["left_road"]) for r in chosen)}
                for key in OUTCOMES:
                    found = spread(values(policy, setting, key), scale="positive")
                    summary[key] = None if found is None else found.as_dict()
                if policy in DESIGNS:
                    for key in ("offset_rms_m", "steering_mae_paper"):
                        diffs = [a - b for a, b in zip(values(policy, setting, key), values("plm", setting, key))]
                        found = spread(diffs, scale="linear")
                        summary[f"{key}_minus_plm"] = None if found is None else found.as_dict()
                    ratios = [a / b for a, b in zip(values(policy, setting, "offset_rms_m"),
                                                    values("ekf", setting, "offset_rms_m")) if b > 0]
                    found = spread(ratios, scale="positive")
                    summary["offset_rms_over_ekf"] = None if found is None else found.as_dict()
                per_policy[policy] = summary
            entry["settings"][setting] = per_policy
        entry["per_unit"] = {
            "names": [part if seed is None else f"seed {seed}" for part, seed in units],
            "settings": {setting: {policy: {
                "offset_rms_m": values(policy, setting, "offset_rms_m"),
                "left_road": [sum(bool(r["left_road"]) for r in rows if r["part"] == part and r["policy"] == policy
                                  and r["setting"] == setting and (seed is None or r["seed"] == seed))
                              for part, seed in units]}
                for policy in POLICIES} for setting in settings}}
        entry["gains"] = gain_ratios(parts)
        entry["verdicts"] = {design: verdict(entry, design) for design in DESIGNS}
        out[group] = entry
    return out


def gain_ratios(parts: list[dict]) -> dict:
    """Per design or PLM-Net and latency: its posed lane-offset and heading gains over its BM's, mean over parts."""
    ratios: dict[str, dict[str, list[float]]] = {}
    for record in parts:
        gains = dict(record["gains"])
        gains.update(record.get("population_gains", {}))
        bm = gains["bm"]
        for who, measured in gains.items():
            if who == "bm":
                continue
            for key in ("offset_gain_per_m", "heading_gain_per_rad"):
                if bm[key]:
                    ratios.setdefault(who, {}).setdefault(key, []).append(measured[key] / bm[key])
    return {who: {key: float(np.mean(v)) for key, v in by_key.items()} for who, by_key in sorted(ratios.items())}


def verdict(entry: dict, design: str) -> dict:
    """Whether ``design`` is recommended (on the road in every run, at every setting where PLM-Net left it; lane-offset
    RMS lower than PLM-Net's with the interval of the paired difference below 0; steering MAE not higher: the mean
    paired difference at most 0) and whether it meets the aim (on the road in every run at :data:`AIM_SETTINGS`,
    mean lane-offset RMS within :data:`AIM_EKF_RATIO` of the EKF lane keeper's, steering MAE no higher than
    PLM-Net's), setting by setting."""
    checks: dict = {"settings": {}}
    for setting, policies in entry["settings"].items():
        mine = policies.get(design)
        if mine is None:
            continue
        offset = mine.get("offset_rms_m_minus_plm") or {}
        mae = mine.get("steering_mae_paper_minus_plm") or {}
        ratio = (mine.get("offset_rms_over_ekf") or {}).get("mean")
        checks["settings"][setting] = {
            "on_road": mine["left_road"] == 0,
            "offset_lower_than_plm": offset.get("ci_high") is not None and offset["ci_high"] < 0,
            "mae_not_higher_than_plm": mae.get("mean") is not None and mae["mean"] <= 0,
            "offset_within_ekf_ratio": ratio is not None and ratio <= AIM_EKF_RATIO,
            "offset_over_ekf": ratio,
        }
    settings = checks["settings"]
    checks["recommended"] = bool(settings) and all(
        s["on_road"] and s["offset_lower_than_plm"] and s["mae_not_higher_than_plm"] for s in settings.values())
    aimed = [settings[s] for s in AIM_SETTINGS if s in settings]
    checks["aim_met"] = bool(aimed) and all(
        s["on_road"] and s["offset_within_ekf_ratio"] and s["mae_not_higher_than_plm"] for s in aimed)
    return checks


# ---------------------------------------------------------------------------------------------------------------
# the study and its report
# ---------------------------------------------------------------------------------------------------------------

RESULT_COLUMNS = ("part", "seed", "policy", "setting", *OUTCOMES, "left_road")


def run_study(parts: list[Part], out: Path, backend=None, batch_size: int = 16, progress: bool = True) -> dict:
    """Drive every part whose committed record is missing or stale, commit it, and render the report from all."""
    records = []
    for part in parts:
        record = read_part(out, part)
        if record is None:
            record = drive_part(part, backend, batch_size, progress)
            if part.record is not None:
                record["population_gains"] = part.record.get("feedback", {})
            write_part(out, record)
        records.append(record)
    return render(out, records)


def render(out: Path, records: list[dict]) -> dict:
    """``mitigations.json``, ``results.csv`` and ``report.md`` from the part records."""
    summary = {"parts": [r["part"] for r in records], "designs": list(DESIGNS), "summary": summarise(records),
               "reference_checks": {r["part"]: r["reference_check"] for r in records if "reference_check" in r}}
    rows = [[row.get(c) for c in RESULT_COLUMNS] for r in records for row in r["rows"]]
    with write_output(out, MITIGATION_REPORT, update=["mitigations.json", "results.csv", "report.md"]) as staged:
        (staged / "mitigations.json").write_text(json_text(summary), encoding="utf-8")
        write_csv_into(staged / "results.csv", RESULT_COLUMNS, rows)
        (staged / "report.md").write_text(report_text(summary), encoding="utf-8")
    return summary


def _interval(entry: dict | None, fmt: str = "{:.3f}") -> str:
    if not entry:
        return "-"
    mean = fmt.format(entry["mean"])
    if entry.get("ci_low") is None:
        return f"{mean} (too few for an interval)"
    return f"{mean} [{fmt.format(entry['ci_low'])}, {fmt.format(entry['ci_high'])}]"


GAIN_NAMES = {"law": "the demonstrator's law (no latency)"}
GROUP_TITLES = {"population": "Population pairs, paper recipe and conditions",
                "shipped": "The shipped default pair, ideal conditions"}


def report_text(summary: dict) -> str:
    lines = ["# Plug-in mitigations around the frozen BM", "",
             "Designs (plm_highway/mitigation): " + "; ".join(f"`{d}`: {POLICY_TITLES[d]}" for d in DESIGNS) + ".",
             "Each keeps the pair's BM frozen and uses only the late frame, its age, the car's speed and yaw-rate "
             "sensor (noise and bias added) and, for `bm-smith`, the BM's posed gains measured on the train track.",
             "Intervals: 95% over pairs (population; each pair its mean over seeds) or over seeds (shipped pair); "
             "positive quantities on the log scale, paired differences (design minus PLM-Net) on the linear scale. "
             "The EKF lane keeper uses no trained model: its runs are the same for every pair (an interval of zero "
             "width over pairs), and the spread of its ratio comes from the designs'.",
             ""]
    for group, entry in summary["summary"].items():
        lines += [f"## {GROUP_TITLES[group]} ({entry['units']} {entry['unit']}s)", ""]
        for setting, policies in entry["settings"].items():
            lines += [f"### {setting}", "",
                      "| policy | lane-offset RMS [m] | offset max [m] | left the road | steering MAE (paper unit) "
                      "| Frechet [m] |", "|---|---|---|---|---|---|"]
            for policy, s in policies.items():
                lines.append(f"| {POLICY_TITLES[policy]} | {_interval(s['offset_rms_m'])} | "
                             f"{_interval(s['offset_max_m'])} | {s['left_road']} of {s['runs']} | "
                             f"{_interval(s['steering_mae_paper'], '{:.4f}')} | {_interval(s['frechet_m'])} |")
            lines += ["", "| design | offset RMS minus PLM-Net's [m] | MAE minus PLM-Net's | offset RMS over the "
                          "EKF's |", "|---|---|---|---|"]
            for design in DESIGNS:
                s = policies.get(design)
                if s:
                    lines.append(f"| {POLICY_TITLES[design]} | {_interval(s['offset_rms_m_minus_plm'])} | "
                                 f"{_interval(s['steering_mae_paper_minus_plm'], '{:.4f}')} | "
                                 f"{_interval(s['offset_rms_over_ekf'], '{:.2f}')} |")
            lines.append("")
        per_unit = entry.get("per_unit")
        if per_unit and entry["unit"] == "pair":
            lines += ["### Per pair: lane-offset RMS [m] (mean over seeds) and runs that left the road", "",
                      "| setting | pair | " + " | ".join(POLICY_TITLES[p] for p in POLICIES) + " |",
                      "|---|---|" + "---|" * len(POLICIES)]
            for setting, by_policy in per_unit["settings"].items():
                for k, name in enumerate(per_unit["names"]):
                    cells = [f"{by_policy[p]['offset_rms_m'][k]:.3f} ({by_policy[p]['left_road'][k]} off)"
                             for p in POLICIES]
                    lines.append(f"| {setting} | {name} | " + " | ".join(cells) + " |")
            lines.append("")
        lines += ["### Posed gains over the BM's (mean over the parts; PLM-Net's from the population's own measurement)", "",
                  "| who | lane-offset gain | heading gain |", "|---|---|---|"]
        for who, ratios in entry["gains"].items():
            lines.append(f"| {GAIN_NAMES.get(who, who)} | {ratios.get('offset_gain_per_m', math.nan):.2f} | "
                         f"{ratios.get('heading_gain_per_rad', math.nan):.2f} |")
        lines += ["", "### Verdicts", ""]
        for design, checks in entry["verdicts"].items():
            lines.append(f"- {POLICY_TITLES[design]}: "
                         f"{'recommended' if checks['recommended'] else 'not recommended'}; the aim (on the road "
                         f"in every run at {', '.join(AIM_SETTINGS)}, offset RMS within {AIM_EKF_RATIO}x the EKF's, "
                         f"MAE no higher than PLM-Net's) {'met' if checks['aim_met'] else 'not met'}.")
            for setting, s in checks["settings"].items():
                failed = [name for name in ("on_road", "offset_lower_than_plm", "mae_not_higher_than_plm",
                                            "offset_within_ekf_ratio") if not s[name]]
                lines.append(f"  - {setting}: {'all checks pass' if not failed else 'fails ' + ', '.join(failed)}"
                             f" (offset RMS {s['offset_over_ekf']:.2f}x the EKF's)" if s["offset_over_ekf"] is not None
                             else f"  - {setting}: {'all checks pass' if not failed else 'fails ' + ', '.join(failed)}")
        lines.append("")
    checks = summary.get("reference_checks") or {}
    if checks:
        same = [part for part, c in checks.items() if c["same"]]
        lines += [f"The reference runs driven for the designs equal the population's in {len(same)} of {len(checks)} "
                  "pairs (lane-offset RMS per seed to 1e-9 m), so the designs' runs and the population's BM and "
                  "PLM-Net runs are judged against the same reference.", ""]
    return "\n".join(lines)


def headline(summary: dict) -> list[str]:
    """One line per group and design: its verdict and its lane at 0.25 s beside PLM-Net's and the EKF's."""
    lines = []
    for group, entry in summary["summary"].items():
        at = entry["settings"].get("const:0.25", {})
        for design in DESIGNS:
            mine, plm, ekf = (at.get(p) or {} for p in (design, "plm", "ekf"))
            if not mine:
                continue
            checks = entry["verdicts"][design]
            lines.append(
                f"{group} ({entry['units']} {entry['unit']}s), 0.25 s: {design} offset RMS "
                f"{_interval(mine.get('offset_rms_m'))} m, left the road {mine['left_road']}/{mine['runs']}; PLM-Net "
                f"{_interval(plm.get('offset_rms_m'))} m, {plm.get('left_road', '-')}/{plm.get('runs', '-')}; EKF "
                f"{_interval(ekf.get('offset_rms_m'))} m; "
                f"{'recommended' if checks['recommended'] else 'not recommended'}, aim "
                f"{'met' if checks['aim_met'] else 'not met'}")
    return lines


def _runs_on_road(entry: dict, policy: str, settings: Sequence[str]) -> tuple[int, int]:
    """(runs that left the road, runs) of ``policy`` over ``settings``."""
    chosen = [entry["settings"][s][policy] for s in settings if policy in entry["settings"].get(s, {})]
    return sum(c["left_road"] for c in chosen), sum(c["runs"] for c in chosen)


WHY_NOT = {"on_road": "it left the road at {}", "offset_lower_than_plm": "its lower lane offset than PLM-Net's is not "
           "shown (interval of the paired difference below 0) at {}", "mae_not_higher_than_plm": "its steering MAE is "
           "above PLM-Net's at {}"}


def why_not(checks: dict) -> str:
    """The recommendation's failed checks, in words, with the settings where each failed."""
    reasons = []
    for check, text in WHY_NOT.items():
        failed = [setting for setting, s in checks["settings"].items() if not s[check]]
        if failed:
            reasons.append(text.format(", ".join(failed)))
    return "; ".join(reasons) or "no setting judged"


def outcome_sentences(summary: dict) -> list[str]:
    """Per group, one sentence: each design's runs off the road at the aim's settings and lane at 0.25 s beside
    PLM-Net's and the EKF lane keeper's, and its verdict."""
    lines = []
    for group, entry in summary["summary"].items():
        aim = [s for s in AIM_SETTINGS if s in entry["settings"]]
        at = entry["settings"].get("const:0.25", {})
        off_plm, runs_plm = _runs_on_road(entry, "plm", aim)
        off_ekf, runs_ekf = _runs_on_road(entry, "ekf", aim)
        parts = []
        for design in DESIGNS:
            off, runs = _runs_on_road(entry, design, aim)
            checks = entry["verdicts"][design]
            parts.append(f"`{design}` left the road in {off} of {runs} runs, lane-offset RMS at 0.25 s "
                         f"{_interval((at.get(design) or {}).get('offset_rms_m'))} m "
                         f"({'recommended' if checks['recommended'] else 'not recommended: ' + why_not(checks)}; "
                         f"the aim {'met' if checks['aim_met'] else 'not met'})")
        where = "population pairs (paper recipe and conditions)" if group == "population" else \
            "seeds with the shipped default pair (ideal conditions)"
        lines.append(f"{entry['units']} {where}, at {', '.join(aim)}: " + "; ".join(parts) +
                     f"; PLM-Net left the road in {off_plm} of {runs_plm} runs "
                     f"({_interval((at.get('plm') or {}).get('offset_rms_m'))} m at 0.25 s), the EKF lane keeper "
                     f"in {off_ekf} of {runs_ekf} ({_interval((at.get('ekf') or {}).get('offset_rms_m'))} m).")
    return lines


def aim_table(summary: dict) -> str:
    """Markdown: per group and aim setting, every policy's lane-offset RMS, runs off the road and steering MAE."""
    out = []
    for group, entry in summary["summary"].items():
        out += [f"**{GROUP_TITLES[group]}** ({entry['units']} {entry['unit']}s; 95% intervals over "
                f"{entry['unit']}s)", "",
                "| setting | policy | lane-offset RMS [m] | left the road | steering MAE (paper unit) |",
                "|---|---|---|---|---|"]
        for setting in (s for s in AIM_SETTINGS if s in entry["settings"]):
            for policy, s in entry["settings"][setting].items():
                out.append(f"| {setting} | {POLICY_TITLES[policy]} | {_interval(s['offset_rms_m'])} | "
                           f"{s['left_road']} of {s['runs']} | {_interval(s['steering_mae_paper'], '{:.4f}')} |")
        out.append("")
    return "\n".join(out).rstrip("\n")
