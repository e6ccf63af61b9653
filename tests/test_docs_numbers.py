"""Numbers quoted in the docs' prose agree with the committed result files they come from."""
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _one_line(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_the_real_car_paragraph_quotes_the_committed_diagnosis():
    diagnosis = json.loads((ROOT / "figures/sim2real/iac_putnam_run4_2/diagnosis.json").read_text(encoding="utf-8"))
    text = _one_line((ROOT / "docs/sim2real.md").read_text(encoding="utf-8"))
    fit = diagnosis["fit"]
    change_pct = round(100.0 * (fit["rmse_after"] / fit["rmse_before"] - 1.0))
    assert f"falls from {fit['rmse_before']:.4f} to {fit['rmse_after']:.4f} rad/s ({change_pct}%)" in text
    assert f"from {fit['position_rmse_before_m']:.2f} to {fit['position_rmse_after_m']:.2f} m" in text
    lag_s = diagnosis["checks"]["yaw_rate_lag_behind_heading"]["lag_s"]
    assert f"its own channel check measures {lag_s:.2f} s" in text
    assert f"Its verdict is `{diagnosis['verdict']}`" in text
    assert not diagnosis["discovery"]["found"] and "Residual discovery names nothing there" in text


def test_the_discovery_benchmark_is_quoted_as_its_report_says():
    report = (ROOT / "figures/sim2real/discovery/report.md").read_text(encoding="utf-8")
    claimed = re.search(r"\*\*Result\*\*: (\d+) of (\d+) effects meet it; (\d+) of (\d+) nulls", report)
    assert claimed, "the benchmark report states its result line"
    lines = report.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| case |"))
    table = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        table.append([cell.strip() for cell in line.strip("|").split("|")])
    effect_rows = [row for row in table if not row[0].startswith("null")]
    met = sum(1 for row in effect_rows if row[-1] == "yes")
    assert (met, len(effect_rows)) == (int(claimed.group(1)), int(claimed.group(2)))
    removed_pct = [int(row[7].rstrip("%")) for row in effect_rows if row[-1] == "yes"]
    docs = _one_line((ROOT / "docs/sim2real.md").read_text(encoding="utf-8"))
    assert (f"{met} of {len(effect_rows)} discovered with the right shape, removing "
            f"{min(removed_pct)}-{max(removed_pct)}% of the held-out error") in docs


def _bench_models(name: str) -> dict:
    return json.loads((ROOT / "figures/bench" / name).read_text(encoding="utf-8"))


def _span(values, digits: int = 2) -> str:
    return f"{min(values):.{digits}f}-{max(values):.{digits}f}"


def test_the_performance_prose_quotes_the_committed_model_benchmarks():
    text = _one_line((ROOT / "docs/performance.md").read_text(encoding="utf-8"))
    runs = [_bench_models(f"models-cpu-{k}.json") for k in (1, 2, 3)]
    random = _bench_models("models-cpu-random.json")["presets"]
    assert (f"(the block below: {random['default']['overhead_ratio']:.3f} and "
            f"{random['paper']['overhead_ratio']:.3f} there)") in text
    sparse = {preset: [run["presets"][preset]["overhead_ratio_vs_sparse_bm"] for run in runs]
              for preset in ("default", "paper")}
    sparse_cpu = {preset: [run["presets"][preset]["overhead_ratio_vs_sparse_bm_cpu"] for run in runs]
                  for preset in ("default", "paper")}
    assert f"PLM-Net over that BM is {_span(sparse['default'])} on the default preset" in text
    assert (f"and {_span(sparse['paper'])} on the paper preset (CPU time {_span(sparse_cpu['default'])} and "
            f"{_span(sparse_cpu['paper'])})") in text
    loads = [run["conditions"]["load_average_1min"] for run in runs]
    assert f"(load average {min(loads):.0f}-{max(loads):.0f})" in text
    added = re.search(r"about ([\d.]+) ms on the default preset and ([\d.]+) ms on the paper preset", text)
    assert added, "the prose states what PLM-Net adds per frame"
    for preset, quoted in zip(("default", "paper"), map(float, added.groups())):
        # "about": the median over the three runs of PLM-Net's CPU time minus the BM's, within 10%
        measured = sorted(run["presets"][preset]["plm_cpu_ms_median"] - run["presets"][preset]["bm_cpu_ms_median"]
                          for run in runs)[1]
        assert abs(measured - quoted) <= 0.1 * measured, (preset, measured, quoted)


def test_the_performance_verdicts_follow_the_committed_env_and_sweep_benchmarks():
    text = _one_line((ROOT / "docs/performance.md").read_text(encoding="utf-8"))
    env = (ROOT / "figures/bench/env.txt").read_text(encoding="utf-8")
    headline = re.search(r"ours / lane-keeping-v0 \(headline\)\s*:\s*([\d.]+)x\s+with latency wrapper\s+([\d.]+)x", env)
    ground = re.search(r"ours / limit \(ground-row warp\)\s*:\s*(\d+)%\s+with latency wrapper\s+(\d+)%", env)
    whole = re.search(r"ours / limit \(whole-frame warp\)\s*:\s*(\d+)%", env)
    assert "at least 10x `lane-keeping-v0` (met, with and without the latency wrapper)" in text
    assert all(float(v) >= 10 for v in headline.groups())
    assert "met against the whole-frame warp, **not met** against the ground-row warp" in text
    assert int(whole.group(1)) >= 60 and all(int(v) < 60 for v in ground.groups())
    sweep = (ROOT / "figures/bench/sweep.txt").read_text(encoding="utf-8")
    speedups = {line[:50].strip(): float(line.split()[-2].rstrip("x")) for line in sweep.splitlines()
                if line.rstrip().endswith(("e+00", "e-04", "e-05", "e-03")) and "x " in line}
    warm = [value for side, value in speedups.items() if side.endswith("warm")]
    assert "**Speed-up target 3x: met** by the warm pool" in text
    assert len(speedups) == 8 and warm == [max(speedups.values())] and warm[0] >= 3.0
    assert all(value < 3.0 for side, value in speedups.items() if not side.endswith("warm"))


def test_the_reliability_memory_row_quotes_the_committed_memory_benchmark():
    memory = json.loads((ROOT / "figures/bench/memory.json").read_text(encoding="utf-8"))
    text = _one_line((ROOT / "docs/reliability.md").read_text(encoding="utf-8"))
    assert (f"{memory['steps']:,} policy steps ({memory['episodes']} episodes, expert on the {memory['track']} track, "
            f"`LatencyWrapper({memory['latency']})`") in text
    assert (f"RSS {memory['rss_after_warmup_mib']:.1f} MiB after a {memory['warmup_steps']:,}-step warm-up, "
            f"{memory['rss_end_mib']:.1f} MiB at the end ({memory['growth_mib']:+.1f} MiB, slope "
            f"{memory['slope_mib_per_100k_steps']:+.2f} MiB per 100k steps; flat within the documented "
            f"{memory['flat_margin_mib']:.0f} MiB margin)") in text
    assert memory["flat"] and abs(memory["growth_mib"]) <= memory["flat_margin_mib"]


def test_the_paper_datas_steering_spread_is_the_shipped_manifests():
    manifest = json.loads((ROOT / "plm_highway/checkpoints/manifest.json").read_text(encoding="utf-8"))
    text = _one_line((ROOT / "docs/expert-and-data.md").read_text(encoding="utf-8"))
    spread = manifest["presets"]["paper"]["data"]["steering_std_paper_units"]
    assert f"labels' std is {spread:.3f} in the paper's unit of 450 deg of hand wheel" in text


def _latency_results() -> dict:
    return json.loads((ROOT / "figures/latency-estimation/results.json").read_text(encoding="utf-8"))


def test_the_latency_pages_words_on_slowness_follow_the_committed_measurement():
    results = _latency_results()
    text = _one_line((ROOT / "docs/latency.md").read_text(encoding="utf-8"))
    plain = [e for e in results["estimation"] if not e["variant"]]
    smooth = [e for e in plain if e["role"] == "estimated" and e["conditions"] == "ideal"
              and e["setting"].startswith("const:")]
    weaving = [e for e in plain if e["role"] == "baseline" and e["setting"].startswith("const:")]
    assert "under the ideal conditions the estimator rarely claims anything within the report's 30-s runs" in text
    assert sum(e["claimed_runs"] for e in smooth) <= 0.25 * sum(e["runs"] for e in smooth)
    paper = [e for e in plain if e["role"] == "estimated" and e["conditions"] == "paper"
             and e["setting"] in ("const:0.15", "const:0.25", "const:0.35")]
    assert "(under the paper conditions, in most runs, after 6 to 25 s)" in text
    assert sum(e["claimed_runs"] for e in paper) > 0.5 * sum(e["runs"] for e in paper)
    assert all(5.5 <= e["first_claim_s"]["mean"] <= 25.0 for e in paper)
    assert "gives the lag away in most runs within about 5 to 9 s" in text
    assert all(e["claimed_runs"] > e["runs"] / 2 and 4.5 <= e["first_claim_s"]["mean"] <= 9.0 for e in weaving)
    varying = [e for e in plain if not e["setting"].startswith("const:")]
    assert "the estimator says \"changing\" rather than a number" in text
    assert sum(e["claims"] for e in varying) <= 0.05 * sum(e["runs"] for e in varying) * 600  # ticks of 30-s runs


def test_the_latency_pages_probe_advice_follows_the_committed_measurement():
    results = _latency_results()
    text = _one_line((ROOT / "docs/latency.md").read_text(encoding="utf-8"))
    by = {(e["conditions"], e["setting"], e["variant"]): e for e in results["estimation"] if e["role"] == "estimated"
          and e["track"] == results["suite"]["robustness_track"]}
    assert ("Under a constant latency it buys a claim within about 4 to 6 s, never a wrong one, for 1.3 to 2 times the "
            "lane-offset RMS of the same runs without it") in text
    setting = results["suite"]["robustness_setting"]
    for conditions in results["suite"]["conditions"]:
        probe, plain = by[(conditions, setting, "probe")], by[(conditions, setting, "")]
        assert 3.5 <= probe["first_claim_s"]["mean"] <= 6.5 and probe["claims"] and probe["wrong_claims"] == 0
        assert 1.25 <= probe["offset_rms_m"]["mean"] / plain["offset_rms_m"]["mean"] <= 2.05
    assert "most of those claims are more than a frame off" in text
    varying = [by[(c, s, "probe")] for c in results["suite"]["conditions"] for s in results["suite"]["probe_settings"]]
    assert any(e["claims"] and e["wrong_claims"] > e["claims"] / 2 for e in varying)
    assert "Every condition keeps its wrong claims at or below 5% but one" in text
    over = [e for e in results["estimation"] if e["claims"] and e["wrong_claims"] > 0.05 * e["claims"]]
    assert len(over) == 1 and over[0]["variant"] == "probe"


def test_the_latency_page_says_most_unanswered_steps_were_unseen():
    results = _latency_results()
    text = _one_line((ROOT / "docs/latency.md").read_text(encoding="utf-8"))
    assert "Most of those steps were *unseen*" in text
    steps = [e["claim_steps"] for e in results["estimation"] if e.get("claim_steps")]
    unanswered = sum(s["steps_judged"] - s["answered"] for s in steps)
    assert unanswered and sum(s["unanswered_not_estimable"] for s in steps) > unanswered / 2
    assert all(s["stopped"] == s["steps_judged"] for s in steps)  # "never claimed the old value past 1 s"
    assert "Steps in a run's first second" in text and results["claim_rules"]["step_blind_s"] == 1.0


def test_the_latency_page_says_the_deployed_method_never_claims_in_a_run():
    results = _latency_results()
    text = _one_line((ROOT / "docs/latency.md").read_text(encoding="utf-8"))
    assert "it needs 150 s of valid driving before its first claim, so it never claims in a 30-s run" in text
    assert results["suite"]["duration_s"] == 30.0
    assert all(e["baselines"]["published"]["claims"] == 0 for e in results["estimation"])


def test_the_bm_response_prose_follows_the_committed_sweeps():
    response = json.loads((ROOT / "figures/bm-response.json").read_text(encoding="utf-8"))
    text = _one_line((ROOT / "docs/calibration.md").read_text(encoding="utf-8"))
    assert ("answers offsets like the law within about 2.5 m, saturates beyond 3 m" in text
            and "answers heading error at about half to nine tenths of the law" in text)
    offset = response["sweeps"]["offset"]
    at = dict(zip(offset["offset_m"], offset["bm"]))
    for offset_m, bm, law in zip(offset["offset_m"], offset["bm"], offset["law"]):
        if abs(offset_m) <= 2.5:  # like the law: within 10% of it (and 0.05 of the range near zero)
            assert abs(bm - law) <= 0.1 * abs(law) + 0.05, (offset_m, bm, law)
        if abs(offset_m) > 3.0:  # saturated: no stronger than at 3 m on that side, while the law grows on
            assert abs(bm) <= 1.1 * abs(at[3.0 if offset_m > 0 else -3.0]) and abs(law) > 1.2 * abs(bm), offset_m
    heading = response["sweeps"]["heading"]
    ratios = [bm / law for bm, law in zip(heading["bm"], heading["law"]) if law != 0]
    assert 0.4 <= min(ratios) <= 0.6 and 0.85 <= max(ratios) <= 1.0, ratios
