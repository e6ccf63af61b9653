"""How many cases the reliability batteries hold, counted from the test files themselves.

docs/reliability.md quotes these counts; ``test_the_readme_quotes_the_battery_sizes``
(tests/test_bad_inputs.py) fails when the two disagree. Run ``python tests/battery_counts.py`` to
print them.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
BATTERIES = ("test_bad_inputs.py", "test_faults.py", "test_env_bad_inputs.py")
README_LINE = re.compile(r"Battery sizes.*")
README_COUNT = re.compile(r"`(test_\w+\.py)` (\d[\d,]*)")


def battery_counts() -> dict[str, int]:
    """file name -> number of test cases pytest collects from it (each parametrisation counts once)."""
    files = [str(REPO_ROOT / "tests" / name) for name in BATTERIES]
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0", "-p", "no:cacheprovider",
                           *files], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(REPO_ROOT), "SDL_VIDEODRIVER": "offscreen",
                               "MPLBACKEND": "Agg"})
    if done.returncode != 0:
        raise RuntimeError(f"collecting the batteries failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    counts = dict.fromkeys(BATTERIES, 0)
    for line in done.stdout.splitlines():
        name = line.split("::", 1)[0].rsplit("/", 1)[-1]
        if "::" in line and name in counts:
            counts[name] += 1
    return counts


def readme_counts(readme: Path = REPO_ROOT / "docs" / "reliability.md") -> dict[str, int]:
    """The counts docs/reliability.md quotes (its "Battery sizes" line)."""
    line = README_LINE.search(readme.read_text(encoding="utf-8"))
    if line is None:
        return {}
    return {name: int(count.replace(",", "")) for name, count in README_COUNT.findall(line.group())}


if __name__ == "__main__":
    for name, count in battery_counts().items():
        print(f"{name} {count}")
