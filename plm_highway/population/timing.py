"""Where a pair's time goes: wall and CPU seconds per stage, with the machine's load beside them.

CPU seconds are this process's (every thread's); a stage whose CPU time is far below ``threads x wall`` waited
(on the disk, or on other work sharing the cores, which the load average shows).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator


def load_average_1min() -> float | None:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:  # not every platform has one
        return None


class StageTimes:
    """``{stage: {"wall_s", "cpu_s", "load_start", "load_end"}}``, filled by :meth:`stage` blocks in order."""

    def __init__(self) -> None:
        self.stages: dict[str, dict] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        wall0, cpu0, load0 = time.perf_counter(), time.process_time(), load_average_1min()
        try:
            yield
        finally:
            self.stages[name] = {"wall_s": round(time.perf_counter() - wall0, 3),
                                 "cpu_s": round(time.process_time() - cpu0, 3),
                                 "load_start": load0, "load_end": load_average_1min()}

    def as_dict(self) -> dict[str, dict]:
        return dict(self.stages)
