"""``plm-highway docs render [--check]``: the numbers README.md and docs/ quote, rendered from committed results."""

from __future__ import annotations

import sys
from pathlib import Path

from plm_highway.cli._common import Command

GROUP_HELP = "the README's and the docs' generated blocks"


def configure_render(parser) -> None:
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 listing the blocks that differ from their committed results")
    parser.add_argument("--root", default=".", help="the project checkout whose README.md and docs/ are rendered")


def run_render(args) -> int:
    from plm_highway.errors import BadInput
    from plm_highway.publish.blocks import render_all
    from plm_highway.publish.renderers import RENDERERS

    root = Path(args.root)
    if not (root / "README.md").is_file():
        raise BadInput(f"{root}: no README.md there; run from the project checkout or pass --root")
    result = render_all(root, RENDERERS, check=args.check)
    for difference, relative in result.missing:
        print(f"not rendered: {difference.path.relative_to(root)} block '{difference.name}': {relative} is not "
              "committed", file=sys.stderr)
    verb = "stale" if args.check else "rendered"
    for difference in result.stale:
        print(f"{verb}: {difference.path.relative_to(root)} block '{difference.name}'")
    if args.check and result.stale:
        print(f"{len(result.stale)} block(s) differ from their committed results: run 'plm-highway docs render'",
              file=sys.stderr)
        return 1
    if not result.stale:
        print("every block matches its committed results")
    return 0


COMMANDS = [Command("render", "render every generated block of README.md and docs/*.md from the committed result "
                    "files (--check: only say which differ)", configure_render, run_render)]
