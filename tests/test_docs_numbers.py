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
