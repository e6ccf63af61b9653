"""``plm-highway sim2real diagnose`` and ``plm-highway sim2real make-recording``."""

from __future__ import annotations

from plm_highway.cli._common import Command, add_overwrite

GROUP_HELP = "find where a simulator and a recording disagree, and why"


def _configure(parser) -> None:
    from plm_highway.sim2real import cli as commands

    commands.configure(parser)
    add_overwrite(parser)


def _run(args) -> int:
    from plm_highway.sim2real import cli as commands

    return commands.run(args)


COMMANDS = [
    Command("diagnose", "locate and explain a sim-vs-recording mismatch", _configure, _run),
    Command("make-recording", "synthesise a recording with concealed physics", _configure, _run),
]
