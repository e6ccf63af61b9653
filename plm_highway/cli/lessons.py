"""``plm-highway lessons build``: the student notebooks from their single source."""

from __future__ import annotations

from plm_highway.cli._common import Command

GROUP_HELP = "build the lessons from their solutions"


def _configure(parser) -> None:
    from plm_highway.grading import notebooks

    notebooks.configure(parser)


def _run(args) -> int:
    from plm_highway.grading import notebooks

    return notebooks.run(args)


COMMANDS = [Command("build", "generate lessons/ from solutions/ (or --check)", _configure, _run)]
