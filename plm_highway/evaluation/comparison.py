"""Comparing the runs of one evaluation: steering of the delayed runs against the reference run.

Runs share the seed and start, so step k of every run is the same instant. A delayed run is compared with the
reference over the steps both reached (a run that left the road ended early), or over the steps all three runs
reached (``span="all"``, the reproduction's protocol: both errors over the same instants).
The reductions are PLM-Net's against the baseline's error, ``100 * (1 - mitigated / baseline)``,
as the paper reports them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from plm_highway.metrics.steering import ERROR_NAMES, common_span, reduction_pct, steering_errors

if TYPE_CHECKING:  # the run module pulls in the simulator; the comparison needs only its columns
    from plm_highway.rollout.closed_loop import RunLog

__all__ = ["steering_comparison"]


RUNS = ("reference", "baseline", "mitigated")


def steering_comparison(logs: Mapping[str, RunLog], span: str = "pair") -> dict:
    """Errors of the ``baseline`` and ``mitigated`` runs' steering against the ``reference`` run's and the
    ``{mae,mse,rmse}_reduction_pct`` between them, each error over the steps its pair reached (``span="pair"``) or
    over the steps all three reached (``"all"``)."""
    steering = {run: logs[run].columns["steering"] for run in RUNS}
    if span == "all":
        steering = dict(zip(RUNS, common_span(*steering.values())))
    elif span != "pair":
        raise ValueError(f"span {span!r}: expected 'pair' or 'all'")
    result: dict = {run: steering_errors(*common_span(steering["reference"], steering[run]))
                    for run in ("baseline", "mitigated")}
    for name in ERROR_NAMES:
        result[f"{name}_reduction_pct"] = reduction_pct(result["baseline"][name], result["mitigated"][name])
    return result
