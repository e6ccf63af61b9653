"""The ``plm-highway`` command line: argparse subparsers over thin adapters, one module per group.

Each adapter module in this package lists its commands as :class:`Command` entries (name, help,
``configure(parser)``, ``run(args) -> int``). Adapters parse options and call library functions,
whose signatures or config dataclasses hold the defaults. Only the command being run (or asked
for ``--help``) is configured, so the library behind the other commands is never imported.

Exit codes: 0 success; 1 a command's own "not OK" answer (e.g. ``lessons build --check``) or a bug;
2 bad input or an environment problem (a missing file, no permission, no space), printed as one
line without a traceback; 130 interrupted. A bug prints its traceback and asks to be reported.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from plm_highway.cli._common import Command, strict_float, strict_int
from plm_highway.errors import BadInput

EXIT_OK, EXIT_BUG, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

# Adapter modules in the order their commands are listed; a group module lists sub-commands.
ADAPTERS = ("demo", "collect", "train", "evaluate", "reproduce", "calibrate", "bm_response", "sweep", "population", "mitigations", "estimate", "bench", "sim2real", "lessons", "docs")


def _adapter(name: str):
    return importlib.import_module(f"plm_highway.cli.{name}")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The full parser tree; only the command named by ``argv``'s leading words gets its options."""
    argv = list(argv or [])
    parser = argparse.ArgumentParser(
        prog="plm-highway",
        description="Perception latency in vision-based lane keeping: simulate, train PLM-Net, evaluate, "
                    "reproduce the paper, diagnose sim2real mismatch, build and grade the lessons.",
        epilog="Run 'plm-highway COMMAND --help' (or 'plm-highway GROUP --help') for a command's options.",
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND")
    for name in ADAPTERS:
        module = _adapter(name)
        group_help = getattr(module, "GROUP_HELP", None)
        if group_help is None:  # a single command
            _add_command(commands, module.COMMANDS[0], (), argv)
            continue
        group = commands.add_parser(name, help=group_help, description=group_help)
        group.set_defaults(_group_parser=group)
        sub = group.add_subparsers(title=f"{name} commands", metavar="COMMAND")
        for command in module.COMMANDS:
            _add_command(sub, command, (name,), argv)
    return parser


def _add_command(subparsers, command: Command, prefix: tuple[str, ...], argv: list[str]) -> None:
    words = (*prefix, command.name)
    parser = subparsers.add_parser(command.name, help=command.help, description=command.description or command.help,
                                   formatter_class=DefaultsOnceFormatter)
    parser.set_defaults(command=" ".join(words), _run=command.run)
    if tuple(argv[:len(words)]) == words:
        command.configure(parser)
        for action in parser._actions:  # every typed option reads ASCII digits only
            if action.type is not None and action.type is not str:
                action.type = _ascii_digits_only(action.type)


class DefaultsOnceFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Adds "(default: X)" to an option's help only where it says something: not where the help already names its
    default, and not for an absent default (None) or an off switch (False)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text or action.default is None or action.default is False:
            return text
        return super()._get_help_string(action)


def _ascii_digits_only(parse):
    """An argparse type that first refuses digits other than 0-9: ``int``/``float`` would read Arabic-Indic or
    full-width digits as numbers that no reader of the command line would take them for."""

    if parse is int or parse is float:  # Python's own would read '1_0' as 10: the kit's strict parsers instead
        def any_float(text: str) -> float:  # nan and inf read, as float() reads them: range checks name them
            return strict_float(text, non_finite=True)

        parse = strict_int if parse is int else any_float

    def checked(text):
        if isinstance(text, str):
            for char in text:
                if not char.isascii() and char.isdecimal():
                    raise argparse.ArgumentTypeError(f"{text!r} holds the non-ASCII digit {char!r}; write numbers "
                                                     "with the digits 0-9")
        return parse(text)

    checked.__name__ = getattr(parse, "__name__", "value")
    return checked


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    if not argv:
        parser.print_help()
        return EXIT_OK
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2), already printed
        return int(exc.code or 0)
    if not hasattr(args, "_run"):  # a group without its sub-command
        args._group_parser.print_help()
        return EXIT_BAD_INPUT
    from plm_highway.io import command_line

    args.command_line = command_line(argv)
    return run_command(args)


def run_command(args: argparse.Namespace) -> int:
    """Run the parsed command; see :data:`BAD_INPUT_ERRORS` for what counts as the user's problem (exit 2).

    Everything else (KeyError, IndexError, RecursionError, OverflowError, RuntimeError, csv.Error,
    gymnasium's errors, ...) is a bug in plm-highway: a bound or a check is missing. It prints its
    traceback and a request to report it, and exits 1, so a bug never looks like bad input.
    """
    from plm_highway.io import protected_inputs

    prefix = f"plm-highway {args.command}: error:"
    try:
        with protected_inputs(input_paths(args)):
            return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print(f"\nplm-highway {args.command}: interrupted; nothing was published", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. piped into `head`
        return EXIT_OK
    except BAD_INPUT_ERRORS as exc:
        print(f"{prefix} {describe_bad_input(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception:
        traceback.print_exc()
        print(f"plm-highway {args.command}: internal error: this is a bug in plm-highway, not in your input. "
              "Please report it with the command line and the traceback above.", file=sys.stderr)
        return EXIT_BUG


# Options that name what a command writes; every other path an option or argument names is an input.
OUTPUT_OPTIONS = frozenset({"out", "json", "json_path", "csv", "report_dir", "lessons"})


def input_paths(args: argparse.Namespace) -> list[str]:
    """Every existing path the command's options and arguments name, outputs aside: no output of the
    command may replace or remove them (:func:`plm_highway.io.protected_inputs`). A value may hold
    several (``trace:a.csv,trace:b.csv``); each piece that names an existing path counts."""
    import os

    found = []
    for name, value in vars(args).items():
        if name.startswith("_") or name in OUTPUT_OPTIONS or name in ("command", "command_line"):
            continue
        for text in value if isinstance(value, (list, tuple)) else [value]:
            if not isinstance(text, str) or not text or "\x00" in text:
                continue
            pieces = {text, text.partition(":")[2]}
            pieces |= {part.partition(":")[2] or part for piece in list(pieces) for part in piece.split(",")}
            found += [piece for piece in sorted(pieces) if piece and os.path.lexists(piece)]
    return found


# What the router answers with exit 2 and one line, without a traceback:
# - BadInput: the project's own input errors (a subclass of ValueError; every check in io, cli, data,
#   models, training, latency and metrics raises it);
# - OSError: the environment (a missing file, PermissionError, IsADirectoryError, NotADirectoryError,
#   no space left), printed with the path;
# - ValueError: the input checks of the rooms that still raise the plain type (road, envs, camera,
#   sim2real, evaluation, lane_ekf, grading). Measured: with (BadInput, OSError, MemoryError) alone,
#   45 of the battery's clean refusals (tests/test_bad_inputs.py) turn into tracebacks, all from road,
#   sim2real, lane_ekf and grading. Once they raise BadInput this entry goes, and a stray ValueError
#   is a bug;
# - MemoryError: a size nobody bounded; the message says so. Every size has a bound checked before
#   work starts, so this is the last line of defence, not the answer to a bad input.
BAD_INPUT_ERRORS = (BadInput, OSError, ValueError, MemoryError)


def describe_bad_input(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return describe_os_error(exc)
    if isinstance(exc, MemoryError):
        return "ran out of memory; reduce the sizes asked for (see the command's --help)"
    return str(exc)


def describe_os_error(exc: OSError) -> str:
    """One line naming the path and what went wrong (no traceback)."""
    where = " -> ".join(repr(str(p)) for p in (exc.filename, exc.filename2) if p is not None)
    reason = exc.strerror or str(exc)
    return f"{where}: {reason}" if where else reason


if __name__ == "__main__":
    sys.exit(main())
