"""``plm-highway bench ...``: benchmarks that print both sides of a comparison and their ratio."""

from __future__ import annotations

import importlib

from plm_highway.cli._common import Command, add_overwrite

GROUP_HELP = "benchmarks: both sides of a comparison in one run, and their ratio"


def _delegate(module_name: str) -> tuple:
    """configure/run of a benchmark module in plm_highway.bench (imported only when that benchmark runs)."""

    def configure(parser) -> None:
        importlib.import_module(f"plm_highway.bench.{module_name}").configure(parser)
        add_overwrite(parser)

    def run(args) -> int:
        return importlib.import_module(f"plm_highway.bench.{module_name}").run(args)

    return configure, run


COMMANDS = [
    Command("env", "env + camera + latency steps/s against highway-env's own camera envs", *_delegate("env")),
    Command("models", "parameter counts and inference time of BM and PLM-Net", *_delegate("models")),
    Command("metrics", "trajectory metrics against similaritymeasures", *_delegate("metrics")),
]
