"""Learned vs model-based latency compensation in the closed loop: PLM-Net beside the delay-compensated EKF.

Both approaches drive the same car (the kit's env), see the road through the same camera with the same
latency (the :class:`~plm_highway.latency.LatencyWrapper`, so both get the same late frames) and are
told the same measured age of each frame:

- ``bm``: the Base Model, fed the late frames (the baseline both approaches mitigate);
- ``plm``: PLM-Net (the Base Model plus its TAPM), told the frame's age;
- ``ekf``: :class:`~plm_highway.estimation.policy.EkfLaneKeepingPolicy`: the lane measured from the late
  frame, re-stamped at its capture time and fused into the lane EKF, which the car's own IMU and
  steering-angle sensor carry to the present; a controller on that estimate.

Per seed, the conditions every policy shares: the track, each latency setting (a time-varying profile's
realisation comes from the seed, identically for all), and a start pose drawn from the seed (lateral
offset uniform in ``+-start_offset_max_m``, heading error uniform in ``+-start_heading_max_rad``), so
the seeds differ for the learned policies too, not only in the EKF's sensor noise (also from the seed).

Measured per run: steering MAE against the **Base Model without latency** from the same start (the
paper's reference, common to all three; over the steps both reached), steering MAE against the policy's
**own** run without latency (what latency costs each approach), RMS and peak lateral offset, whether it
left the road, the trajectory metrics of the whole run against the lane centre
(:func:`plm_highway.evaluation.trajectory.run_trajectory_metrics`), and the compute per policy step
(wall clock of the policy call, frame to steering, on whatever the machine is doing at the time).
Robustness: PLM-Net and the EKF told a latency that is off by each of ``biases_s`` at ``bias_latency``.

Summaries are means over seeds with 95 % Student-t intervals, and per condition the paired difference
EKF minus PLM-Net (same seed, same conditions) with its interval: where that interval excludes 0, one
approach is measurably worse there.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from tqdm import tqdm

from plm_highway.metrics.intervals import mean_ci
from plm_highway.rollout.backends import LocalPool

POLICIES = ("bm", "plm", "ekf")
POLICY_LABELS = {"bm": "Base Model", "plm": "PLM-Net", "ekf": "EKF (delay-compensated)"}
RUN_METRICS = ("steering_mae_vs_bm_ref", "steering_mae_vs_own_ref", "lateral_offset_rms_m", "lateral_offset_max_m",
               "left_road", "completed_fraction", "frechet_dist_m", "dtw", "area_between_two_curves_m2",
               "ms_per_step")
METRIC_LABELS = {"steering_mae_vs_bm_ref": "steering MAE vs BM without latency",
                 "steering_mae_vs_own_ref": "steering MAE vs own run without latency",
                 "lateral_offset_rms_m": "offset RMS [m]", "lateral_offset_max_m": "offset peak [m]",
                 "left_road": "left the road (fraction of seeds)", "completed_fraction": "track completed",
                 "frechet_dist_m": "Frechet [m]", "dtw": "DTW", "area_between_two_curves_m2": "area [m^2]",
                 "ms_per_step": "compute per step [ms]"}
TRAJECTORY_KEYS = {"frechet_dist_m": "frechet_dist", "dtw": "dtw", "area_between_two_curves_m2": "area_between_two_curves"}
MAX_SEEDS = 100


@dataclass(frozen=True)
class CompareConfig:
    """The conditions of the comparison (shared by every policy)."""

    track: str = "test"
    settings: tuple[str, ...] = ("const:0.15", "const:0.2", "const:0.25", "const:0.3", "steps:0.0-0.35:1.0")
    bias_latency: str = "const:0.25"
    biases_s: tuple[float, ...] = (-0.1, -0.05, 0.05, 0.1)
    start_offset_max_m: float = 0.3
    start_heading_max_rad: float = 0.02
    max_steps: int | None = None  # None: the whole track

    def __post_init__(self):
        from plm_highway.latency import parse_profile

        if not self.settings:
            raise ValueError("CompareConfig.settings: at least one latency setting is needed")
        for spec in (*self.settings, self.bias_latency):
            parse_profile(spec)
        for bias in self.biases_s:
            if not (math.isfinite(bias) and abs(bias) <= 0.5):
                raise ValueError(f"CompareConfig.biases_s: {bias!r} must be within +-0.5 s")
        if not (0 <= self.start_offset_max_m <= 1.0 and 0 <= self.start_heading_max_rad <= 0.1):
            raise ValueError("CompareConfig: start_offset_max_m must be in [0, 1] m and start_heading_max_rad in "
                             "[0, 0.1] rad")
        if self.max_steps is not None and self.max_steps < 2:
            raise ValueError(f"CompareConfig.max_steps={self.max_steps!r} must be at least 2")


def start_pose(seed: int, config: CompareConfig) -> dict:
    """The seed's start pose, as env config overrides (the same for every policy of that seed)."""
    rng = np.random.default_rng([seed, 20250610])
    return {"start_offset_m": float(rng.uniform(-1, 1) * config.start_offset_max_m),
            "start_heading_error_rad": float(rng.uniform(-1, 1) * config.start_heading_max_rad)}


class TimedPolicy:
    """Forwards to a policy and adds up the wall clock of its calls (frame to steering)."""

    def __init__(self, policy):
        self.policy = policy
        self.seconds = 0.0
        self.calls = 0

    def reset(self) -> None:
        self.policy.reset()
        self.seconds, self.calls = 0.0, 0

    def __call__(self, frame, info) -> float:
        start = time.perf_counter()
        steering = self.policy(frame, info)
        self.seconds += time.perf_counter() - start
        self.calls += 1
        return steering

    @property
    def ms_per_step(self) -> float:
        return 1000.0 * self.seconds / max(self.calls, 1)


@dataclass(frozen=True)
class RunRow:
    policy: str
    latency: str
    bias_s: float
    seed: int
    metrics: dict  # RUN_METRICS -> value (None where undefined)


@dataclass
class CompareResult:
    config: CompareConfig
    seeds: tuple[int, ...]
    rows: list[RunRow] = field(default_factory=list)

    def values(self, policy: str, latency: str, bias_s: float, metric: str) -> list[float]:
        """The metric over the seeds (in seed order), skipping undefined values."""
        out = []
        for seed in self.seeds:
            for row in self.rows:
                if (row.policy, row.latency, row.seed) == (policy, latency, seed) and abs(row.bias_s - bias_s) < 1e-9:
                    value = row.metrics.get(metric)
                    if value is not None:
                        out.append(float(value))
        return out

    def summary(self, policy: str, latency: str, bias_s: float = 0.0) -> dict:
        return {metric: _interval(self.values(policy, latency, bias_s, metric)) for metric in RUN_METRICS}

    def paired_difference(self, latency: str, metric: str, bias_s: float = 0.0, first="ekf", second="plm") -> dict:
        """``first - second`` per seed (same conditions), mean and 95 % interval."""
        a = dict(self._by_seed(first, latency, bias_s, metric))
        b = dict(self._by_seed(second, latency, bias_s, metric))
        diffs = [a[s] - b[s] for s in self.seeds if s in a and s in b]
        return _interval(diffs)

    def _by_seed(self, policy, latency, bias_s, metric):
        for row in self.rows:
            if (row.policy, row.latency) == (policy, latency) and abs(row.bias_s - bias_s) < 1e-9:
                if row.metrics.get(metric) is not None:
                    yield row.seed, float(row.metrics[metric])

    def to_dict(self) -> dict:
        conditions = [(spec, 0.0) for spec in self.config.settings]
        conditions += [(self.config.bias_latency, b) for b in self.config.biases_s]
        summary = []
        for spec, bias in conditions:
            policies = POLICIES if bias == 0.0 else ("plm", "ekf")
            summary.append({
                "latency": spec, "bias_s": bias,
                "policies": {p: self.summary(p, spec, bias) for p in policies},
                "ekf_minus_plm": {m: self.paired_difference(spec, m, bias) for m in RUN_METRICS},
            })
        return {
            "command": "plm-highway estimate compare",
            "config": asdict(self.config),
            "seeds": list(self.seeds),
            "reference": "the Base Model without latency from the same start pose (steering_mae_vs_bm_ref); each "
                         "policy's own run without latency (steering_mae_vs_own_ref)",
            "interval": "mean over seeds and 95 % Student-t interval; paired differences per seed",
            "no_latency": {p: self.summary(p, "const:0") for p in ("bm", "ekf")},
            "summary": summary,
            "runs": [asdict(row) for row in self.rows],
        }


def _interval(values) -> dict:
    """Mean and 95% interval over the seeds; None where undefined (no values, one value's interval, or a value
    that is not finite)."""
    if not values or not all(math.isfinite(v) for v in values):
        return {"mean": None, "low": None, "high": None, "n": len(values)}
    return mean_ci(values).as_dict()


def planned_runs(config: CompareConfig) -> list[tuple[str, str, float]]:
    """(policy, latency spec, bias) of one seed's runs; the no-latency references come first."""
    runs = [("bm", "const:0", 0.0), ("ekf", "const:0", 0.0)]
    for spec in config.settings:
        runs += [(policy, spec, 0.0) for policy in POLICIES]
    for bias in config.biases_s:
        runs += [("plm", config.bias_latency, bias), ("ekf", config.bias_latency, bias)]
    return runs


def compare(seeds: int = 5, config: CompareConfig = CompareConfig(), checkpoints=None, workers: int = 1,
            progress: bool = True, policy_factory=None) -> CompareResult:
    """Drive every planned run for seeds ``0 .. seeds-1`` and measure them (see the module docstring).

    ``workers`` > 1 drives that many seeds at once in worker processes (the results do not depend on it).
    ``policy_factory(name, latency_bias_s, seed)`` makes a policy (default:
    :func:`plm_highway.rollout.policies.make_policy` with ``checkpoints``); tests pass small ones.
    """
    from plm_highway.evaluation.evaluate import check_inputs

    if not 1 <= seeds <= MAX_SEEDS:
        raise ValueError(f"seeds={seeds!r}: must be in [1, {MAX_SEEDS}]")
    if not 1 <= workers <= 16:
        raise ValueError(f"workers={workers!r}: must be in [1, 16]")
    check_inputs(config.track, "const:0", config.max_steps)
    for spec in config.settings:
        check_inputs(config.track, spec)
    if policy_factory is None:
        from plm_highway.rollout.policies import checkpoint_pair

        checkpoint_pair(checkpoints)  # missing checkpoints fail now, not in the first worker
    result = CompareResult(config, tuple(range(seeds)))
    runs_per_seed = len(planned_runs(config))
    bar = tqdm(total=seeds * runs_per_seed, desc="compare", unit="run", disable=not progress, file=sys.stderr)
    if workers == 1:
        for seed in result.seeds:
            result.rows += run_seed(seed, config, checkpoints, policy_factory, bar)
    else:
        by_seed: dict[int, list[RunRow]] = {}
        with LocalPool(workers) as pool:
            for index, rows in pool.map_unordered(functools.partial(run_seed, config=config, checkpoints=checkpoints),
                                                  result.seeds):
                by_seed[index] = rows
                bar.update(runs_per_seed)
        for index in range(len(result.seeds)):
            result.rows += by_seed[index]
    bar.close()
    return result


def run_seed(seed: int, config: CompareConfig, checkpoints=None, policy_factory=None, bar=None) -> list[RunRow]:
    """Every planned run of one seed, measured."""
    from plm_highway.evaluation.evaluate import run_steps
    from plm_highway.evaluation.trajectory import LaneCentre, run_trajectory_metrics, start_lane_offset_m
    from plm_highway.metrics.steering import common_span, steering_mae
    from plm_highway.road.track import resolve_track
    from plm_highway.rollout.cells import run_cells
    from plm_highway.rollout.closed_loop import RunCell
    from plm_highway.rollout.policies import make_policy, single_threaded_inference

    if policy_factory is None:
        def policy_factory(name, latency_bias_s, seed):
            return make_policy(name, checkpoints, latency_bias_s=latency_bias_s, seed=seed)
    track_spec = resolve_track(config.track)
    max_steps = run_steps(track_spec, config.max_steps)
    centre = LaneCentre(track_spec, start_lane_offset_m(track_spec))
    pose = start_pose(seed, config)
    references: dict[str, np.ndarray] = {}
    rows = []
    with single_threaded_inference():
        for policy_name, spec, bias in planned_runs(config):
            if bar is not None:
                bar.set_postfix_str(f"seed {seed} {policy_name} {spec} {bias:+.2f}", refresh=False)
            timed = TimedPolicy(policy_factory(policy_name, bias, seed))  # made per run: one model at a time
            [log] = run_cells([RunCell(policy_name, timed, track_spec, spec, seed, env_config=pose, max_steps=max_steps)],
                              serial=True)
            if bar is not None:
                bar.update()
            if spec == "const:0":
                references[policy_name] = log.columns["steering"]
            # PLM-Net's own reference is the paper's: its Base Model without latency.
            own = references["bm" if policy_name == "plm" else policy_name]
            full = run_trajectory_metrics(log.columns, track_spec, centre)["full"]
            summary = log.summary()
            metrics = {
                "steering_mae_vs_bm_ref": steering_mae(*common_span(references["bm"], log.columns["steering"])),
                "steering_mae_vs_own_ref": steering_mae(*common_span(own, log.columns["steering"])),
                "lateral_offset_rms_m": summary["lateral_offset_rms_m"],
                "lateral_offset_max_m": summary["lateral_offset_max_m"],
                "left_road": float(summary["left_road"]),
                "completed_fraction": summary["completed_fraction"],
                **{key: _finite_or_none(full.get(name)) for key, name in TRAJECTORY_KEYS.items()},
                "ms_per_step": timed.ms_per_step,
            }
            rows.append(RunRow(policy_name, spec, bias, seed, metrics))
    return rows


def _finite_or_none(value):
    return None if value is None or not math.isfinite(float(value)) else float(value)


# ---------------------------------------------------------------------------------------------
# report: markdown, figure, files
# ---------------------------------------------------------------------------------------------

TABLE_METRICS = ("steering_mae_vs_bm_ref", "steering_mae_vs_own_ref", "lateral_offset_rms_m", "lateral_offset_max_m",
                 "left_road", "frechet_dist_m", "ms_per_step")


def _cell(interval: dict, digits: int = 3) -> str:
    if interval["mean"] is None:
        return "n/a"
    if interval["low"] is None:
        return f"{interval['mean']:.{digits}f}"
    return f"{interval['mean']:.{digits}f} [{interval['low']:.{digits}f}, {interval['high']:.{digits}f}]"


def verdict(difference: dict, lower_is_better: bool = True) -> str:
    """Which approach the paired interval favours: ``EKF worse``, ``PLM-Net worse`` or ``no clear difference``."""
    if difference["low"] is None or difference["mean"] is None:
        return "n/a"
    if difference["low"] > 0:
        return "EKF worse" if lower_is_better else "PLM-Net worse"
    if difference["high"] < 0:
        return "PLM-Net worse" if lower_is_better else "EKF worse"
    return "no clear difference"


def condition_label(spec: str, bias_s: float) -> str:
    return spec if bias_s == 0.0 else f"{spec}, told {bias_s:+.2f} s off"


def markdown(data: dict) -> str:
    """The comparison as a report (``data`` from :meth:`CompareResult.to_dict`)."""
    config = data["config"]
    lines = [
        "# Learned vs model-based latency compensation: PLM-Net beside the delay-compensated EKF", "",
        f"Command: `{data['command']}`. Track `{config['track']}` "
        f"({'first ' + str(config['max_steps']) + ' policy steps' if config['max_steps'] else 'whole track'}), "
        f"seeds {data['seeds'][0]}..{data['seeds'][-1]} "
        f"({len(data['seeds'])}); each seed fixes the start pose (offset within +-{config['start_offset_max_m']} m, "
        f"heading within +-{config['start_heading_max_rad']} rad), the time-varying latency's realisation and the "
        "EKF's sensor noise, identically for every policy. Cells: mean over seeds [95 % Student-t interval]. "
        "Steering MAE in normalised steering units (action +-1 = +-0.2 rad at the wheel).", "",
        "References: *vs BM ref* = the Base Model driving the same start without latency (the paper's reference, "
        "common to all); *vs own ref* = the policy's own run without latency (PLM-Net: its Base Model). "
        "Compute per step: wall clock of one policy call (frame to steering), on a shared, loaded machine.", "",
        "## No latency", "",
        "| policy | " + " | ".join(METRIC_LABELS[m] for m in TABLE_METRICS) + " |",
        "|---" * (len(TABLE_METRICS) + 1) + "|",
    ]
    for policy, summary in data["no_latency"].items():
        lines.append(f"| {POLICY_LABELS[policy]} | " + " | ".join(_cell(summary[m]) for m in TABLE_METRICS) + " |")
    lines += ["", "## With latency", ""]
    for entry in data["summary"]:
        lines += [f"### {condition_label(entry['latency'], entry['bias_s'])}", "",
                  "| policy | " + " | ".join(METRIC_LABELS[m] for m in TABLE_METRICS) + " |",
                  "|---" * (len(TABLE_METRICS) + 1) + "|"]
        for policy, summary in entry["policies"].items():
            lines.append(f"| {POLICY_LABELS[policy]} | " + " | ".join(_cell(summary[m]) for m in TABLE_METRICS) + " |")
        diff = entry["ekf_minus_plm"]
        lines.append("| EKF - PLM-Net (paired) | " + " | ".join(
            f"{_cell(diff[m])} ({verdict(diff[m])})" for m in TABLE_METRICS) + " |")
        lines.append("")
    lines += ["## Where each is worse", ""] + where_worse(data) + [""]
    return "\n".join(lines)


def where_worse(data: dict) -> list[str]:
    """One line per condition: the paired verdicts on steering MAE (vs BM ref) and offset RMS."""
    out = []
    for entry in data["summary"]:
        diff = entry["ekf_minus_plm"]
        parts = [f"{label}: {verdict(diff[m])} ({_cell(diff[m])})"
                 for m, label in (("steering_mae_vs_bm_ref", "steering MAE"), ("lateral_offset_rms_m", "offset RMS"),
                                  ("frechet_dist_m", "Frechet"))]
        out.append(f"- {condition_label(entry['latency'], entry['bias_s'])}: " + "; ".join(parts))
    return out


def plot_comparison(data: dict, path) -> None:
    """Steering MAE and offset RMS per latency setting (three policies), and both under a misestimated latency."""
    from plm_highway.io import pyplot, save_figure_into

    plt = pyplot()
    settings = [e for e in data["summary"] if e["bias_s"] == 0.0]
    biased = [e for e in data["summary"] if e["bias_s"] != 0.0]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    colours = {"bm": "tab:gray", "plm": "tab:blue", "ekf": "tab:red"}
    x = np.arange(len(settings))
    for ax, metric in zip(axes[:2], ("steering_mae_vs_bm_ref", "lateral_offset_rms_m")):
        for k, policy in enumerate(POLICIES):
            means, errs = _bars(settings, policy, metric)
            ax.bar(x + (k - 1) * 0.27, means, 0.27, yerr=errs, capsize=3, color=colours[policy],
                   label=POLICY_LABELS[policy])
        ax.set_xticks(x, [e["latency"].replace("steps:0.0-0.35:1.0", "time-varying\n0-0.35 s") for e in settings],
                      fontsize=8)
        ax.set_xlabel("latency setting")
        ax.set_ylabel(METRIC_LABELS[metric])
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    ax = axes[2]
    if biased:
        spec = biased[0]["latency"]
        base = next((e for e in settings if e["latency"] == spec), None)
        for policy in ("plm", "ekf"):
            entries = sorted(biased + ([base] if base else []), key=lambda e: e["bias_s"])
            means, errs = _bars(entries, policy, "steering_mae_vs_bm_ref")
            ax.errorbar([e["bias_s"] for e in entries], means, yerr=errs, marker="o", capsize=3, color=colours[policy],
                        label=POLICY_LABELS[policy])
        ax.set_xlabel(f"latency estimate minus true latency [s] (true: {spec})")
        ax.set_ylabel(METRIC_LABELS["steering_mae_vs_bm_ref"])
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle(f"PLM-Net vs delay-compensated EKF on track {data['config']['track']}, "
                 f"{len(data['seeds'])} seeds (bars: mean, whiskers: 95 % CI)")
    fig.tight_layout()
    save_figure_into(fig, path, dpi=110)
    plt.close(fig)


def _bars(entries, policy, metric):
    means, errs = [], [[], []]
    for entry in entries:
        cell = entry["policies"][policy][metric]
        mean = cell["mean"] if cell["mean"] is not None else np.nan
        means.append(mean)
        errs[0].append(mean - cell["low"] if cell["low"] is not None else 0.0)
        errs[1].append(cell["high"] - mean if cell["high"] is not None else 0.0)
    return means, errs
