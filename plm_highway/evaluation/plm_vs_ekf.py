"""Learned vs model-based latency compensation in the closed loop: PLM-Net beside the delay-compensated EKF.

Five policies drive the same track under the same conditions (``ideal`` or ``paper``, :mod:`plm_highway.rollout.conditions`:
loop rate, camera, latency injection, image noise, actuator and processing delay, steering range, start
perturbation), see the road through the same camera with the same latency and are told the same latency:

- ``bm``: the Base Model; at 0 s it is the **reference** every run is judged against, with latency the
  baseline both answers mitigate;
- ``plm``: PLM-Net (the Base Model plus its TAPM), told the latency the conditions tell it;
- ``ekf_nc``: the EKF lane keeper (:class:`~plm_highway.lane_ekf.policy.EkfLaneKeepingPolicy`) fusing each
  late frame as if it were current (no delay compensation);
- ``ekf``: the same re-stamping each frame at its capture time and re-running the filter to now.

Its plant (camera, loop, actuator, processing delay, steering range, car) is the conditions'
(:func:`~plm_highway.rollout.policies.ekf_plant`). At 0 s the two EKF variants are one run (a frame's
capture is now), driven once as ``ekf``.

Settings: no latency, each constant latency and the time-varying profile, every policy at the same latency
(under the paper conditions' legacy FIFO too: the Base Model is not held at a constant latency here, so all
policies face the same frames). Each seed fixes the start perturbation, the time-varying latency's realisation,
the image noise and the EKF's sensor noise, identically for every policy. Every run drives the whole scored track
(:func:`~plm_highway.rollout.conditions.scored_steps`) and is measured by
:func:`plm_highway.evaluation.outcomes.run_outcomes` against the Base Model's run of the same seed without latency.

Summaries: mean over seeds with a 95 % Student-t interval, and per setting paired differences (same seed, same
conditions): EKF - PLM-Net (which answer wins), EKF - EKF without compensation (what re-stamping buys) and
PLM-Net - Base Model (what the TAPM buys). Where a paired interval excludes 0, one side is measurably worse there.
"""

from __future__ import annotations

import math
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
from tqdm import tqdm

from plm_highway.errors import BadInput
from plm_highway.evaluation.evaluate import check_inputs
from plm_highway.evaluation.outcomes import run_outcomes
from plm_highway.evaluation.protocol import setting_label
from plm_highway.io import pyplot, save_figure_into
from plm_highway.latency.profiles import check_specs
from plm_highway.metrics.intervals import interval_text, mean_ci
from plm_highway.road.track import resolve_track
from plm_highway.rollout.cells import Cell, check_env, drive_options, run_cells
from plm_highway.rollout.closed_loop import RunCell
from plm_highway.rollout.conditions import CONDITIONS, scored_steps
from plm_highway.rollout.policies import checkpoint_pair, make_policy, single_threaded_inference

POLICIES = ("bm", "plm", "ekf_nc", "ekf")
POLICY_LABELS = {"bm": "Base Model", "plm": "PLM-Net", "ekf_nc": "EKF lane keeper, no delay compensation",
                 "ekf": "EKF lane keeper, delay compensated"}
NO_LATENCY = "const:0"
REFERENCE = ("bm", NO_LATENCY, 0.0)
# Numeric outcomes summarised over seeds (left_road as the fraction of seeds); see plm_highway.evaluation.outcomes.
SUMMARISED = ("steering_mae_paper", "steering_mae_paper_common", "offset_rms_m", "offset_max_m", "offset_rms_driven_m",
              "frechet_m", "left_road")
METRIC_LABELS = {"steering_mae_paper": "steering MAE, whole track (paper unit)",
                 "steering_mae_paper_common": "steering MAE, common span (paper unit)",
                 "offset_rms_m": "offset RMS [m]", "offset_max_m": "offset max [m]",
                 "offset_rms_driven_m": "offset RMS, driven [m]", "frechet_m": "Frechet to reference [m]",
                 "left_road": "left the road (fraction of seeds)"}
PAIRS = (("ekf", "plm"), ("ekf", "ekf_nc"), ("plm", "bm"))  # paired differences: first - second
PAIR_METRICS = ("steering_mae_paper", "offset_rms_m", "offset_max_m", "frechet_m")
MAX_SEEDS = 100


@dataclass(frozen=True)
class CompareConfig:
    """What every policy shares: the track, the conditions, the latency settings and the misestimates."""

    conditions: str = "ideal"
    track: str = "test"
    settings: tuple[str, ...] = ("const:0.15", "const:0.2", "const:0.25", "const:0.3", "steps:0.0-0.35:1.0")
    bias_latency: str = "const:0.25"
    biases_s: tuple[float, ...] = ()  # PLM-Net and the EKF told a latency off by each of these at bias_latency
    max_steps: int | None = None  # None: the whole scored track

    def __post_init__(self):
        if self.conditions not in CONDITIONS:
            raise BadInput(f"--conditions {self.conditions!r}: expected one of {list(CONDITIONS)}")
        if not self.settings:
            raise BadInput("--settings: at least one latency setting is needed")
        check_specs((*self.settings, self.bias_latency))
        if NO_LATENCY in self.settings:
            raise BadInput(f"--settings: {NO_LATENCY} is always driven (the reference); give the latencies only")
        for bias in self.biases_s:
            if not (math.isfinite(bias) and abs(bias) <= 0.5 and bias != 0.0):
                raise BadInput(f"--biases: {bias!r} must be a nonzero number of seconds within +-0.5")
        if self.max_steps is not None and self.max_steps < 2:
            raise BadInput(f"--max-steps {self.max_steps!r}: must be at least 2")


def planned_runs(config: CompareConfig) -> list[tuple[str, str, float]]:
    """(policy, latency spec, bias) of one seed's runs: the reference first, then no latency, every latency
    setting, the misestimates."""
    runs = [REFERENCE, ("plm", NO_LATENCY, 0.0), ("ekf", NO_LATENCY, 0.0)]
    for spec in config.settings:
        runs += [(policy, spec, 0.0) for policy in POLICIES]
    for bias in config.biases_s:
        runs += [("plm", config.bias_latency, bias), ("ekf", config.bias_latency, bias)]
    return runs


@dataclass(frozen=True)
class RunRow:
    policy: str
    latency: str
    bias_s: float
    seed: int
    outcomes: dict  # plm_highway.evaluation.outcomes.OUTCOMES -> value


@dataclass
class CompareResult:
    config: CompareConfig
    seeds: tuple[int, ...]
    rows: list[RunRow] = field(default_factory=list)
    steps_scored: int | None = None

    def by_seed(self, policy: str, latency: str, bias_s: float, metric: str) -> dict[int, float]:
        """seed -> the metric's value (``left_road`` as 0/1); seeds where it is undefined are left out."""
        out = {}
        for row in self.rows:
            if (row.policy, row.latency) == (policy, latency) and abs(row.bias_s - bias_s) < 1e-9:
                value = row.outcomes.get(metric)
                if value is not None and math.isfinite(float(value)):
                    out[row.seed] = float(value)
        return out

    def summary(self, policy: str, latency: str, bias_s: float = 0.0) -> dict:
        return {metric: _interval(list(self.by_seed(policy, latency, bias_s, metric).values()),
                                  "linear" if metric == "left_road" else "positive", metric == "left_road")
                for metric in SUMMARISED}

    def paired_difference(self, latency: str, metric: str, first: str, second: str, bias_s: float = 0.0) -> dict:
        """``first - second`` per seed (same seed, same conditions): mean and 95 % interval."""
        a = self.by_seed(first, latency, bias_s, metric)
        b = self.by_seed(second, latency, bias_s, metric)
        return _interval([a[s] - b[s] for s in self.seeds if s in a and s in b])

    def to_dict(self) -> dict:
        conditions = CONDITIONS[self.config.conditions]
        entries = [{"latency": NO_LATENCY, "bias_s": 0.0,
                    "policies": {p: self.summary(p, NO_LATENCY) for p in ("bm", "plm", "ekf")},
                    "paired": {f"{a}-{b}": {m: self.paired_difference(NO_LATENCY, m, a, b) for m in PAIR_METRICS}
                               for a, b in (("ekf", "plm"), ("plm", "bm"))}}]
        for spec in self.config.settings:
            entries.append({"latency": spec, "bias_s": 0.0, "policies": {p: self.summary(p, spec) for p in POLICIES},
                            "paired": {f"{a}-{b}": {m: self.paired_difference(spec, m, a, b) for m in PAIR_METRICS}
                                       for a, b in PAIRS}})
        for bias in self.config.biases_s:
            spec = self.config.bias_latency
            entries.append({"latency": spec, "bias_s": bias,
                            "policies": {p: self.summary(p, spec, bias) for p in ("plm", "ekf")},
                            "paired": {"ekf-plm": {m: self.paired_difference(spec, m, "ekf", "plm", bias)
                                                   for m in PAIR_METRICS}}})
        return {
            "command": command_line(self.config, len(self.seeds)),
            "config": asdict(self.config),
            "conditions": {"name": conditions.name, "policy_frequency_hz": conditions.policy_frequency_hz,
                           "injection": conditions.injection, "latency_source": conditions.latency_source,
                           "image_noise_std": conditions.image_noise_std,
                           "steering_time_constant_s": conditions.steering_time_constant_s,
                           "processing_delay_steps": conditions.processing_delay_steps,
                           "max_steering_rad": conditions.max_steering_rad,
                           "checkpoint_preset": conditions.checkpoint_preset},
            "seeds": list(self.seeds),
            "steps_scored": self.steps_scored,
            "reference": "the Base Model of the same seed and start without latency (plm_highway.evaluation.outcomes)",
            "interval": "mean over seeds and 95 % Student-t interval; paired differences per seed",
            "settings": entries,
            "runs": [asdict(row) for row in self.rows],
        }


def _interval(values: list[float], scale: str = "linear", share: bool = False) -> dict:
    """Mean and 95% interval over seeds: an outcome (an error, never negative) on the log scale, a paired
    difference on the linear one (:mod:`plm_highway.metrics.intervals`); a ``share`` (the fraction of seeds that
    left the road) on the linear one, clipped to [0, 1]."""
    if not values:
        return {"mean": None, "low": None, "high": None, "n": 0}
    interval = mean_ci(values, scale=scale).as_dict()
    if share and interval["low"] is not None:  # a share: no interval reaches outside [0, 1]
        interval.update(low=max(0.0, interval["low"]), high=min(1.0, interval["high"]))
    return interval


def command_line(config: CompareConfig, seeds: int) -> str:
    """The ``plm-highway estimate compare`` line for one condition (what differs from the defaults)."""
    default = CompareConfig()
    parts = ["plm-highway estimate compare", f"--conditions {config.conditions}", f"--seeds {seeds}"]
    if config.track != default.track:
        parts.append(f"--track {config.track}")
    if config.settings != default.settings:
        parts.append(f"--settings {','.join(config.settings)}")
    if config.biases_s:
        parts.append(f"--biases={','.join(f'{b:g}' for b in config.biases_s)}")
        if config.bias_latency != default.bias_latency:
            parts.append(f"--bias-latency {config.bias_latency}")
    if config.max_steps is not None:
        parts.append(f"--max-steps {config.max_steps}")
    return " ".join(parts)


def compare(seeds: int = 5, config: CompareConfig = CompareConfig(), checkpoints=None, workers: int = 1,
            progress: bool = True) -> CompareResult:
    """Drive every planned run for seeds ``0 .. seeds-1`` and measure them (see the module docstring).

    ``workers`` > 1 drives that many seeds at once in spawned worker processes (the results do not depend on it).
    """
    if not 1 <= seeds <= MAX_SEEDS:
        raise BadInput(f"--seeds {seeds!r}: must be in [1, {MAX_SEEDS}]")
    if not 1 <= workers <= 16:
        raise BadInput(f"--workers {workers!r}: must be in [1, 16]")
    conditions = CONDITIONS[config.conditions]
    track_spec, _ = check_inputs(config.track, NO_LATENCY, config.max_steps)
    for spec in (*config.settings, config.bias_latency):
        check_env(track_spec, spec, conditions)  # the latency must fit the buffer at these rates
    checkpoint_pair(checkpoints, conditions.checkpoint_preset)  # missing checkpoints fail now, not in a worker
    result = CompareResult(config, tuple(range(seeds)), steps_scored=scored_steps(track_spec, conditions,
                                                                                    config.max_steps))
    runs_per_seed = len(planned_runs(config))
    bar = tqdm(total=seeds * runs_per_seed, desc=f"compare {config.conditions}", unit="run", disable=not progress,
               file=sys.stderr)
    if workers == 1:
        for seed in result.seeds:
            result.rows += run_seed(seed, config, checkpoints, lambda: bar.update())
    else:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = [pool.submit(run_seed, seed, config, None if checkpoints is None else str(checkpoints))
                       for seed in result.seeds]
            for future in futures:  # in seed order, so the rows do not depend on the workers
                result.rows += future.result()
                bar.update(runs_per_seed)
    bar.close()
    return result


def run_seed(seed: int, config: CompareConfig, checkpoints=None, tick=None) -> list[RunRow]:
    """Every planned run of one seed, driven batched (one forward pass per model and step; the EKF lane keepers,
    each its own object, called per run) and measured against the seed's reference run."""
    conditions = CONDITIONS[config.conditions]
    track_spec = resolve_track(config.track)
    steps = scored_steps(track_spec, conditions, config.max_steps)
    planned = planned_runs(config)
    cells = []
    for policy, spec, bias in planned:
        if policy.startswith("ekf"):
            driver = make_policy("ekf", seed=seed, conditions=conditions, latency_bias_s=bias,
                                 compensate_delay=policy == "ekf")
        else:
            driver = policy  # named: loaded once, batched with every run of the same model
        options = drive_options(Cell(policy, policy, spec, seed), conditions, steps)
        cells.append(RunCell(f"{policy} {spec} {bias:+g}", driver, track_spec, spec, seed,
                             latency_bias_s=bias if policy == "plm" else 0.0,
                             latency_source=conditions.latency_source, **options))
    with single_threaded_inference():
        logs = run_cells(cells, checkpoints, preset=conditions.checkpoint_preset,
                         on_done=None if tick is None else (lambda index, log: tick()))
    reference = logs[planned.index(REFERENCE)]
    return [RunRow(policy, spec, bias, seed, run_outcomes(log, reference, track_spec, conditions.max_steering_rad))
            for (policy, spec, bias), log in zip(planned, logs)]


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------

TABLE_METRICS = ("steering_mae_paper", "steering_mae_paper_common", "offset_rms_m", "offset_max_m", "frechet_m",
                 "left_road")


def cell(interval: dict, digits: int = 3) -> str:
    if interval["mean"] is None:
        return "n/a"

    return interval_text(interval["mean"], interval["low"], interval["high"], interval.get("n", 0),
                         lambda value: f"{value:.{digits}f}", short=True)


def verdict(difference: dict, first: str, second: str) -> str:
    """Which side a paired interval of ``first - second`` (lower is better) favours."""
    if difference["low"] is None or difference["mean"] is None:
        return "n/a"
    if difference["low"] > 0:
        return f"{POLICY_LABELS[second]} better"
    if difference["high"] < 0:
        return f"{POLICY_LABELS[first]} better"
    return "no clear difference"


def setting_name(spec: str, bias_s: float = 0.0) -> str:
    label = "no latency" if spec == NO_LATENCY else setting_label(spec)
    return label if bias_s == 0.0 else f"{label}, told {bias_s:+.2f} s off"


def who_wins(entry: dict, metric: str) -> str:
    """``EKF``, ``PLM-Net`` or ``neither`` on one setting's paired EKF - PLM-Net difference of ``metric``."""
    difference = entry["paired"]["ekf-plm"][metric]
    if difference["low"] is None:
        return "n/a"
    if difference["high"] < 0:
        return "EKF"
    if difference["low"] > 0:
        return "PLM-Net"
    return "neither"


def markdown(reports: list[dict]) -> str:
    """The comparison under each set of conditions (``reports``: :meth:`CompareResult.to_dict` of each)."""
    lines = ["# Learned vs model-based latency compensation: PLM-Net beside the EKF lane keeper", "",
             "Commands: " + "; ".join(f"`{data['command']} --out DIR`" for data in reports) + " (one directory: "
             "`--conditions " + ",".join(data["config"]["conditions"] for data in reports) + "`).", "",
             "Every run is judged against the Base Model of the same seed and start without latency, over the whole "
             "scored track (`plm_highway.evaluation.outcomes`): steering MAE in the paper's unit (1 = 450 deg of "
             "steering wheel), every step missed after leaving the road counted as an error of 1 (normalised), and "
             "over the common span; lateral offset from the lane centre (RMS and max); Frechet distance between the "
             "run's path and the reference's. Cells: mean over seeds [95 % Student-t interval], on the quantity's "
             "scale (`plm_highway.metrics.intervals`): errors, offsets and distances with the interval of their "
             "logarithms, so never below 0; the fraction of seeds that left the road on the linear scale, clipped to "
             "[0, 1]; paired differences on the linear scale.", "",
             "## Who wins where (paired EKF lane keeper, delay compensated, minus PLM-Net)", "",
             "| conditions | setting | steering MAE | offset RMS | Frechet | left the road: PLM-Net / EKF |",
             "|---|---|---|---|---|---|"]
    for data in reports:
        for entry in data["settings"]:
            left = (f"{_count(entry, 'plm')} / {_count(entry, 'ekf')}")
            lines.append(f"| {data['config']['conditions']} | {setting_name(entry['latency'], entry['bias_s'])} | "
                         + " | ".join(f"{who_wins(entry, m)} ({cell(entry['paired']['ekf-plm'][m])})"
                                      for m in ("steering_mae_paper", "offset_rms_m", "frechet_m"))
                         + f" | {left} |")
    for data in reports:
        conditions = data["conditions"]
        lines += ["", f"## Conditions `{conditions['name']}`", "",
                  f"Track `{data['config']['track']}`, {data['steps_scored']} steps at {conditions['policy_frequency_hz']} "
                  f"Hz, seeds {data['seeds'][0]}..{data['seeds'][-1]}; latency injection {conditions['injection']}, "
                  f"PLM-Net told the {conditions['latency_source']} latency; image noise {conditions['image_noise_std']:g}"
                  f" grey levels; actuator {conditions['steering_time_constant_s']:g} s, processing delay "
                  f"{conditions['processing_delay_steps']} steps, steering +-{conditions['max_steering_rad']:g} rad; "
                  f"checkpoints `{conditions['checkpoint_preset']}`.", ""]
        for entry in data["settings"]:
            lines += [f"### {setting_name(entry['latency'], entry['bias_s'])}", "",
                      "| policy | " + " | ".join(METRIC_LABELS[m] for m in TABLE_METRICS) + " |",
                      "|---" * (len(TABLE_METRICS) + 1) + "|"]
            for policy, summary in entry["policies"].items():
                label = "Base Model (the reference)" if (policy, entry["latency"]) == REFERENCE[:2] else POLICY_LABELS[policy]
                lines.append(f"| {label} | " + " | ".join(cell(summary[m]) for m in TABLE_METRICS) + " |")
            for pair, differences in entry["paired"].items():
                first, second = pair.split("-")
                lines.append(f"| {POLICY_LABELS[first]} - {POLICY_LABELS[second]} (paired) | "
                             + " | ".join(f"{cell(differences[m])} ({verdict(differences[m], first, second)})"
                                          if m in differences else "" for m in TABLE_METRICS) + " |")
            lines.append("")
    return "\n".join(lines)


def _count(entry: dict, policy: str) -> str:
    summary = entry["policies"].get(policy)
    if summary is None or summary["left_road"]["mean"] is None:
        return "n/a"
    n = summary["left_road"]["n"]
    return f"{round(summary['left_road']['mean'] * n)} of {n}"


def plot_comparison(reports: list[dict], path) -> None:
    """Offset RMS and steering MAE against the latency setting, one row of panels per set of conditions."""
    plt = pyplot()
    fig, axes = plt.subplots(len(reports), 2, figsize=(14, 4.4 * len(reports)), squeeze=False)
    colours = {"bm": "tab:gray", "plm": "tab:blue", "ekf_nc": "tab:orange", "ekf": "tab:red"}
    for row, data in zip(axes, reports):
        entries = [e for e in data["settings"] if e["bias_s"] == 0.0]
        x = np.arange(len(entries))
        for ax, metric in zip(row, ("offset_rms_m", "steering_mae_paper")):
            for k, policy in enumerate(POLICIES):
                means, errors = [], [[], []]
                for entry in entries:
                    summary = entry["policies"].get(policy) or entry["policies"].get(
                        "ekf" if policy == "ekf_nc" else policy)
                    value = summary[metric]
                    mean = np.nan if value["mean"] is None else value["mean"]
                    means.append(mean)
                    errors[0].append(0.0 if value["low"] is None else mean - value["low"])
                    errors[1].append(0.0 if value["high"] is None else value["high"] - mean)
                ax.bar(x + (k - 1.5) * 0.2, means, 0.2, yerr=errors, capsize=2, color=colours[policy],
                       label=POLICY_LABELS[policy])
            ax.set_xticks(x, [setting_name(e["latency"]).replace(", redrawn", ",\nredrawn") for e in entries], fontsize=7)
            ax.set_xlabel("latency setting")
            ax.set_ylabel(METRIC_LABELS[metric])
            ax.set_title(f"conditions {data['config']['conditions']}")
            ax.grid(axis="y", alpha=0.3)
        row[0].legend(fontsize=7)
    fig.suptitle(f"PLM-Net vs the EKF lane keeper on track {reports[0]['config']['track']}, "
                 f"{len(reports[0]['seeds'])} seeds (bars: mean, whiskers: 95 % CI)")
    fig.tight_layout()
    save_figure_into(fig, path, dpi=110)
    plt.close(fig)
