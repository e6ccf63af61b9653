"""The commands of one README section's first ```bash block, one a line (what CI runs verbatim).

    python .ci/readme_commands.py "Quick start"

CI runs the README's Quick start and test commands from the README itself, so the two cannot diverge.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def commands(section: str, readme: Path = README) -> list[str]:
    text = readme.read_text(encoding="utf-8")
    heading = re.search(rf"^## {re.escape(section)}\n(?P<body>.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    if heading is None:
        raise SystemExit(f"{readme}: no '## {section}' section")
    block = re.search(r"^```bash\n(?P<code>.*?)^```", heading["body"], re.MULTILINE | re.DOTALL)
    if block is None:
        raise SystemExit(f"{readme}: section '## {section}' has no ```bash block")
    lines = [line.strip() for line in block["code"].splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


if __name__ == "__main__":
    print("\n".join(commands(sys.argv[1])))
