"""``plm-highway bench models`` on a device, and the README's figures as the committed result files render them."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest
import torch

from plm_highway import cli
from plm_highway.bench.models import BATCH_SIZES, format_runs

ROOT = Path(__file__).resolve().parents[1]
CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(
    not CUDA, reason=f"no CUDA device: torch {torch.__version__} (CUDA build: {torch.version.cuda}) sees no GPU"
)
README_BLOCK = re.compile(r"<!-- bench-models-runs: (?P<files>[^>]*?) -->\n(?P<body>.*?)\n<!-- /bench-models-runs -->",
                          re.DOTALL)


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=needs_cuda)])
def test_bench_models_reports_latency_throughput_and_training_on_the_device(tmp_path, capsys, device):
    out = tmp_path / "bench.json"
    threads = str(torch.get_num_threads())  # leave this worker's thread count as it was
    argv = ["bench", "models", "--preset", "default", "--weights", "random", "--frames", "6", "--warmup", "1",
            "--repeats", "1", "--train-batches", "1", "--threads", threads, "--device", device, "--json", str(out)]
    assert cli.main(argv) == 0
    result = json.loads(out.read_text())
    assert result["conditions"]["device"].split(":")[0] == device
    assert result["command"] == "plm-highway " + " ".join(argv)
    figures = result["presets"]["default"]
    for side in ("bm", "plm", "plm_reference"):
        assert figures[f"{side}_ms_median"] > 0
    assert figures["overhead_ratio"] == pytest.approx(figures["plm_ms_median"] / figures["bm_ms_median"])
    for model in ("bm", "plm"):
        assert set(figures["throughput_samples_per_s"][model]) == {str(b) for b in BATCH_SIZES} == {"1", "32", "256"}
        assert all(rate > 0 for rate in figures["throughput_samples_per_s"][model].values())
    assert figures["training_samples_per_s"]["bm"] > 0 and figures["training_samples_per_s"]["tapm"] > 0
    assert figures["max_abs_difference_fused_vs_reference"] < 1e-6
    assert ("int8_overhead_ratio" in figures) == (device == "cpu")  # quantised kernels: CPU only
    # The paper's figures beside ours (Section 4.8, RTX 2080 Ti).
    assert (result["paper"]["bm_ms"], result["paper"]["plm_net_ms"]) == (2.352, 5.909)
    printed = capsys.readouterr().out
    assert "BM 2.352 ms, PLM-Net 5.909 ms, ratio 2.512" in printed and "RTX 2080 Ti" in printed
    assert "batch 1, 32, 256" in printed


def committed_runs() -> tuple[list[Path], str]:
    match = README_BLOCK.search((ROOT / "README.md").read_text(encoding="utf-8"))
    assert match, "README.md has no bench-models-runs block"
    return [ROOT / name for name in match["files"].split()], match["body"]


def test_the_readme_shows_the_committed_bench_models_runs():
    paths, body = committed_runs()
    assert len(paths) >= 3  # the target is judged on the median of three runs
    results = [json.loads(path.read_text(encoding="utf-8")) for path in paths]
    assert all(result["conditions"]["weights"] == "shipped" for result in results)
    assert body == "\n".join(["```text", *format_runs(results), "```"])


def test_format_runs_judges_the_median_of_the_runs():
    result = json.loads(committed_runs()[0][0].read_text(encoding="utf-8"))
    runs = []
    for default_ratio, paper_ratio in ((1.30, 1.10), (1.20, 1.40), (1.10, 1.26)):
        run = copy.deepcopy(result)
        run["presets"]["default"]["overhead_ratio"] = default_ratio
        run["presets"]["paper"]["overhead_ratio"] = paper_ratio
        runs.append(run)
    assert format_runs(runs)[-2].endswith("default 1.200 meets, paper 1.260 MISSES")
