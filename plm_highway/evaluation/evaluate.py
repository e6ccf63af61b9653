"""Closed-loop comparison runs (``plm-highway evaluate``): reference, baseline (and mitigated).

- ``reference``: the policy without latency;
- ``baseline``: the same policy fed the delayed observations;
- ``mitigated`` (``--policy plm``): PLM-Net fed the delayed observations and told their age; (``--policy bm-warp``
  or ``bm-smith``) the BM with a plug-in mitigation (:mod:`plm_highway.mitigation`) told the same age.

With ``--policy ekf`` the three runs are the model-based policy's own (seed paper 004): the EKF
lane keeper without latency, fusing each late frame as if it were current (no delay
compensation), and re-stamping it at its measured capture time and re-estimating to now; under
``--conditions paper`` its controller's plant is those conditions' loop, actuator, processing delay
and steering range (:func:`~plm_highway.rollout.policies.ekf_plant`).
All runs share the track and the seed, so the same latency realisation.

The JSON holds ``track``, ``latency``, ``policy``, ``seed``, ``runs`` (per-run summary),
``steering`` (with ``--policy plm``: errors against the reference and PLM-Net's reductions),
``trajectory`` (``{part: {run: {metric: value}}}``, parts full/straight/left/right, see
:mod:`plm_highway.evaluation.trajectory`) and ``trajectory_method``. An output directory
(``--out``) holds ``result.json``, one CSV per run (``RUN.csv``, every logged column) and
``steps.csv`` with all runs side by side, published together. Inputs (track, latency spec,
checkpoints, step limit) are checked before any run starts, and nothing is written unless every
run and metric succeeded.
"""

from __future__ import annotations

from plm_highway.errors import BadInput
from plm_highway.evaluation import protocol
from plm_highway.evaluation.trajectory import trajectory_method, trajectory_metrics
from plm_highway.io import directory_kind, file_kind, json_text, write_csv_into, write_outputs
from plm_highway.latency import LatencyProfile, parse_profile
from plm_highway.road.track import TrackSpec, resolve_track
from plm_highway.rollout.cells import Cell, drive_options, run_cells, runs_under
from plm_highway.rollout.closed_loop import ESTIMATE_COLUMNS, LOG_COLUMNS, RunLog, drive, make_env
from plm_highway.rollout.conditions import (
    CONDITIONS,
    Conditions,
    baseline_latency,
    scored_steps,
    with_injection,
    with_latency_source,
)
from plm_highway.rollout.policies import MITIGATING_POLICIES, make_policy, policy_kind
from plm_highway.rollout.seeds import parse_seeds

COMBINED_COLUMNS = ("steering", "latency_s", "observation_age_s", "x_m", "y_m", "lateral_offset_m", "segment")


EVALUATION_JSON = file_kind("evaluation", "an evaluation result JSON file")
EVALUATION_DIR = directory_kind("evaluation-run", "a plm-highway evaluation directory")


def check_inputs(track, latency, max_steps=None) -> tuple[TrackSpec, LatencyProfile]:
    """The boundary of a run's inputs: the track resolved to its spec and the latency spec parsed to its profile,
    each once, and checked the way the runs will use them (the latency must fit the wrapper's buffer)."""
    track_spec = resolve_track(track)
    profile = parse_profile(latency)
    make_env(track_spec, profile).close()
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"--max-steps {max_steps}: must be at least 1")
    return track_spec, profile


def run_steps(track_spec: TrackSpec, max_steps: int | None, conditions: Conditions = CONDITIONS["ideal"]) -> int | None:
    """Steps each run drives under ``conditions``: one lap of a closed track, an open track until the
    camera could first see its end (:func:`plm_highway.rollout.conditions.scored_steps`), at most ``max_steps``."""
    return scored_steps(track_spec, conditions, max_steps)


def compare_runs(logs: dict[str, RunLog], track_spec: TrackSpec, latency_spec: str, policy: str, seed: int,
                 track_label: str | None = None) -> dict:
    """The result dict of runs already driven (``reference``, ``baseline``, optionally ``mitigated``) on
    ``track_spec``; ``track_label``: the track as the user named it (default: the spec's name)."""
    result = {"track": track_label or track_spec.name, "latency": latency_spec,
              "policy": policy, "seed": seed, "runs": {name: log.summary() for name, log in logs.items()}}
    if "mitigated" in logs:
        result["steering"] = protocol.steering_over_common_span(logs)
    result["trajectory"] = trajectory_metrics(logs, track_spec)
    result["trajectory_method"] = trajectory_method(track_spec)
    return result


RUN_TITLES = {"reference": "reference (no latency)", "baseline": "baseline (with latency)",
              "mitigated": "mitigated (with latency)"}


def summary_lines(result: dict) -> list[str]:
    """A short human summary of an evaluation: per run the lane (lateral-offset RMS and maximum, whether it left
    the road) beside the steering MAE against the reference (normalised steering, 1 = full lock), first seed."""
    steering = result.get("steering") or {}
    conditions = f", {result['conditions']} conditions" if result.get("conditions") else ""
    lines = [f"{result['policy']} on track {result['track']}, latency {result['latency']}, seed {result['seed']}"
             f"{conditions}:",
             f"{'run':<26} {'offset RMS':>11} {'offset max':>11} {'left road':>10} {'steering MAE':>13}"]
    for name, run in result["runs"].items():
        mae = steering.get(name, {}).get("mae") if isinstance(steering.get(name), dict) else None
        lines.append(f"{RUN_TITLES.get(name, name):<26} {run['lateral_offset_rms_m']:>9.3f} m "
                     f"{run['lateral_offset_max_m']:>9.3f} m {'yes' if run['left_road'] else 'no':>10} "
                     f"{'-' if mae is None else f'{mae:.4f}':>13}")
    if steering.get("mae_reduction_pct") is not None:
        baseline, mitigated = result["runs"]["baseline"], result["runs"]["mitigated"]
        offset_change = 100.0 * (1.0 - mitigated["lateral_offset_rms_m"] / baseline["lateral_offset_rms_m"])
        who = "PLM-Net" if result["policy"] == "plm" else result["policy"]
        lines.append(f"reduction by {who} against the baseline: steering MAE {steering['mae_reduction_pct']:.1f}%, "
                     f"lateral-offset RMS {offset_change:.1f}% (negative: higher)")
    return lines


def evaluate(track="test", latency="const:0.25", policy="plm", *, seed=0, max_steps=None, checkpoints=None,
             seeds=None, conditions: str = "ideal", injection: str | None = None, device="cpu",
             latency_source: str | None = None) -> tuple[dict, dict]:
    """Run the comparison; returns (result dict, {run name: RunLog}).

    ``seeds`` (a count N: seeds ``seed .. seed+N-1``, or a list): every run once per seed, each seed with its own
    start perturbation (:func:`plm_highway.rollout.conditions.start_perturbation`); the result is the first seed's, plus
    ``seeds``, ``per_seed`` (each seed's ``runs`` and ``steering``) and ``over_seeds`` (mean and 95% CI of every
    steering error and reduction). Without ``seeds``: the single run of ``seed``, centred start (as before).

    ``conditions`` (``ideal`` or ``paper``, as for ``reproduce``): the loop rate, pipeline, camera, latency
    injection, image noise and checkpoint preset of those conditions; under ``paper`` every run, single or
    per seed, is driven as ``reproduce`` drives it (a seed above 0 also perturbs the start). ``injection``
    (``--injection``) replaces the conditions' latency injection, as for ``reproduce``.

    ``latency_source`` (``--latency-source``; None: the conditions' own) is what the mitigation is told: the
    ``measured`` age of the frame, the ``requested`` latency, or the latency ``estimated`` from the stream without
    capture timestamps (:mod:`plm_highway.lane_ekf.latency_stream`): PLM-Net interpolates by it, the EKF
    re-stamps by it, and every run logs it (``latency_estimate_s``, ``latency_estimable``) beside the true age.
    """
    if conditions not in CONDITIONS:
        raise BadInput(f"--conditions {conditions!r}: expected one of {list(CONDITIONS)}")
    chosen = with_latency_source(with_injection(CONDITIONS[conditions], injection), latency_source)
    track_label = track.name if isinstance(track, TrackSpec) else str(track)
    track_spec, profile = check_inputs(track, latency, max_steps)
    latency_spec = profile.spec
    max_steps = run_steps(track_spec, max_steps, CONDITIONS[conditions])
    if policy == "ekf":
        if seeds is not None:  # each seed needs its own sensor-noise stream; compare over seeds with 'estimate compare'
            raise BadInput("--seeds with --policy ekf: not supported by evaluate; use 'plm-highway estimate compare'")
        logs = _drive_ekf(track_spec, latency_spec, seed, max_steps, chosen,
                          as_conditions=conditions != "ideal" or injection is not None,
                          latency_source=latency_source or "measured")
        result = compare_runs(logs, track_spec, latency_spec, policy, seed, track_label)
        return _with_options(result, conditions, injection, latency_source), logs
    if seeds is not None or conditions != "ideal" or injection is not None:
        seed_list = [seed] if seeds is None else parse_seeds(seeds, seed)
        result, logs = _evaluate_seeds(track_label, track_spec, latency_spec, policy, seed_list, max_steps,
                                       checkpoints, chosen, device)
        if seeds is None:  # one run per role: no per-seed summary
            for key in ("seeds", "per_seed", "over_seeds"):
                result.pop(key, None)
        return _with_options(result, conditions, injection, latency_source), logs
    base_policy = policy_kind(policy).reference
    policies = {"reference": make_policy(base_policy, checkpoints, device=device),
                "baseline": make_policy(base_policy, checkpoints, device=device)}
    if policy in MITIGATING_POLICIES:
        policies["mitigated"] = make_policy(policy, checkpoints, latency_source=chosen.latency_source, device=device,
                                            seed=seed, conditions=chosen)
    logs = {}
    for name, run_policy in policies.items():
        logs[name] = drive(name, run_policy, track_spec, "const:0" if name == "reference" else profile, seed,
                           max_steps=max_steps, latency_estimation=chosen.latency_estimation)
    result = compare_runs(logs, track_spec, latency_spec, policy, seed, track_label)
    return _with_options(result, conditions, injection, latency_source), logs


def _with_options(result: dict, conditions: str, injection: str | None, latency_source: str | None) -> dict:
    """``result`` with the options that changed how its runs were driven (none recorded at their defaults)."""
    if conditions != "ideal":
        result["conditions"] = conditions
    if injection is not None:
        result["injection"] = injection
    if latency_source is not None:
        result["latency_source"] = latency_source
    return result


def _drive_ekf(track_spec: TrackSpec, latency_spec: str, seed: int, max_steps: int | None, chosen: Conditions,
               as_conditions: bool, latency_source: str = "measured") -> dict[str, RunLog]:
    """The EKF lane keeper's three runs: without latency, late frames fused as if current, late frames re-stamped.

    Its plant (camera, steering range, loop, actuator lag, processing delay, car) is ``chosen``'s
    (:func:`~plm_highway.rollout.policies.ekf_plant`). ``as_conditions``: drive as ``reproduce`` drives the
    conditions (their env settings, injection, image noise, start perturbation); otherwise the default env
    from a centred start, as the other policies' single runs under the ideal conditions. ``latency_source``: what
    the re-stamping EKF re-stamps by (``estimated``: the latency estimated from the stream, which every run of
    ``chosen`` then estimates and logs).
    """
    runs = {"reference": ("const:0", True), "baseline": (latency_spec, False), "mitigated": (latency_spec, True)}
    logs = {}
    for role, (latency, compensate) in runs.items():
        policy = make_policy("ekf", seed=seed, conditions=chosen, compensate_delay=compensate,
                             latency_source=latency_source if compensate and role == "mitigated" else "measured")
        options = (drive_options(Cell(role, "ekf", latency, seed), chosen, max_steps) if as_conditions
                   else {"max_steps": max_steps, "latency_estimation": chosen.latency_estimation})
        logs[role] = drive(role, policy, track_spec, latency, seed, **options)
    return logs


def _evaluate_seeds(track_label: str, track_spec: TrackSpec, latency_spec: str, policy: str, seeds: list[int],
                    max_steps: int | None, checkpoints, chosen: Conditions, device="cpu") -> tuple[dict, dict]:
    """The runs of every seed under the conditions ``chosen``."""
    base_policy = policy_kind(policy).reference
    # The model policies loaded once here; the expert is made per run by the runner.
    policies = {} if base_policy == "expert" else {"bm": make_policy("bm", checkpoints, preset=chosen.checkpoint_preset,
                                                                             device=device)}
    roles = {"reference": base_policy, "baseline": base_policy}
    if policy == "plm":
        policies["plm"] = make_policy("plm", checkpoints, latency_source=chosen.latency_source,
                                      preset=chosen.checkpoint_preset, device=device)
    if policy in MITIGATING_POLICIES:  # a plug-in mitigation is made per run by the runner (its state is the run's)
        roles["mitigated"] = policy
    driven = {"reference": "const:0", "baseline": baseline_latency(latency_spec, chosen), "mitigated": latency_spec}
    cells = [Cell(role, who, driven[role], seed, setting=latency_spec) for seed in seeds for role, who in roles.items()]
    # Batched (one forward pass per model and step); batch-invariant models: each run is its one-env run.
    logs = run_cells(runs_under(cells, track_spec, chosen, policies, max_steps), checkpoints,
                     preset=chosen.checkpoint_preset, device=device)
    per_seed_logs = [dict(zip(roles, logs[k:k + len(roles)])) for k in range(0, len(logs), len(roles))]
    first = compare_runs(per_seed_logs[0], track_spec, latency_spec, policy, seeds[0], track_label)
    first["seeds"] = seeds
    first["per_seed"] = [{"seed": seed, "runs": {name: log.summary() for name, log in seed_logs.items()},
                          **({"steering": protocol.steering_over_common_span(seed_logs)}
                             if policy in MITIGATING_POLICIES else {})}
                         for seed, seed_logs in zip(seeds, per_seed_logs)]
    if policy in MITIGATING_POLICIES:
        first["over_seeds"] = {"steering": protocol.estimates_as_dict(
            protocol.aggregate_steering([entry["steering"] for entry in first["per_seed"]]))}
    return first, per_seed_logs[0]


def combined_rows(logs: dict[str, RunLog]) -> tuple[list[str], list[list]]:
    """All runs side by side, one row per policy step: ``t_s`` then ``RUN_COLUMN`` for each run.

    Step k is the same instant in every run; a run that ended earlier has empty cells.
    """
    longest = max(logs.values(), key=lambda log: log.steps)
    columns = {name: COMBINED_COLUMNS + tuple(c for c in ESTIMATE_COLUMNS if c in log.columns)
               for name, log in logs.items()}
    header = ["t_s"] + [f"{name}_{column}" for name in logs for column in columns[name]]
    rows = []
    for k in range(longest.steps):
        row = [longest.columns["t_s"][k]]
        for name, log in logs.items():
            row += [log.columns[c][k] if k < log.steps else "" for c in columns[name]]
        rows.append(row)
    return header, rows


def log_columns(log: RunLog) -> tuple[str, ...]:
    """The columns a run's CSV holds: every logged column, and the latency estimate's where the run made one."""
    return LOG_COLUMNS + tuple(column for column in ESTIMATE_COLUMNS if column in log.columns)


def log_rows(log: RunLog) -> list[list]:
    return [list(row) for row in zip(*(log.columns[column] for column in log_columns(log)))]


def publish_results(result: dict, logs: dict[str, RunLog], json_path=None, out_dir=None, overwrite: bool = False
                    ) -> None:
    """The result JSON (``json_path``) and/or the run directory (``out_dir``), published together."""
    targets = [(path, kind) for path, kind in ((json_path, EVALUATION_JSON), (out_dir, EVALUATION_DIR)) if path]
    with write_outputs(targets, overwrite=overwrite) as staged:
        for (_, kind), path in zip(targets, staged):
            if kind is EVALUATION_JSON:
                path.write_text(json_text(result, EVALUATION_JSON), encoding="utf-8")
                continue
            (path / "result.json").write_text(json_text(result, EVALUATION_JSON), encoding="utf-8")
            for name, log in logs.items():
                write_csv_into(path / f"{name}.csv", log_columns(log), log_rows(log))
            write_csv_into(path / "steps.csv", *combined_rows(logs))
