"""The ``plm-highway`` command line.

Each command lives in the module that owns the work; this file only routes to it, importing the
module lazily so that ``plm-highway --help`` and light commands do not pay for torch.
Every command module defines ``configure(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# "words": (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo zigzag": ("plm_highway.evaluation.demo", "Figure 2: the lane keeper with and without latency"),
    "collect": ("plm_highway.data.collect", "record expert demonstrations with recovery perturbations"),
    "evaluate": ("plm_highway.evaluation.cli", "closed-loop reference / baseline / mitigated runs"),
    "reproduce": ("plm_highway.evaluation.reproduce", "the paper's tables and figures on the test track"),
    "train bm": ("plm_highway.training.cli", "train the Base Model"),
    "train tapm": ("plm_highway.training.cli", "train the Timed Action Prediction Model"),
    "bench env": ("plm_highway.bench.env", "env + camera + latency steps/s against racetrack-large-v0"),
    "bench models": ("plm_highway.bench.models", "parameter counts and inference time of BM and PLM-Net"),
    "bench metrics": ("plm_highway.bench.metrics", "trajectory metrics against similaritymeasures"),
    "sim2real diagnose": ("plm_highway.sim2real.cli", "locate and explain a sim-vs-recording mismatch"),
    "sim2real make-recording": ("plm_highway.sim2real.cli", "synthesise a recording with concealed physics"),
    "lessons build": ("plm_highway.grading.notebooks", "generate lessons/ from solutions/ (or --check)"),
}

EXIT_BAD_INPUT = 2


def _usage() -> str:
    width = max(len(words) for words in COMMANDS)
    lines = ["usage: plm-highway COMMAND [options]", "", "commands:"]
    lines += [f"  {words:<{width}}  {help_text}" for words, (_, help_text) in COMMANDS.items()]
    lines += ["", "Run 'plm-highway COMMAND --help' for a command's options."]
    return "\n".join(lines)


def _match_command(argv: list[str]) -> tuple[str, list[str]] | None:
    for n_words in (2, 1):
        words = " ".join(argv[:n_words])
        if words in COMMANDS:
            return words, argv[n_words:]
    return None


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    matched = _match_command(argv)
    if matched is None:
        print(f"plm-highway: unknown command {' '.join(argv[:2])!r}\n\n{_usage()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    words, rest = matched
    module = importlib.import_module(COMMANDS[words][0])
    parser = argparse.ArgumentParser(prog=f"plm-highway {words}", description=COMMANDS[words][1])
    parser.set_defaults(command=words)
    module.configure(parser)
    args = parser.parse_args(rest)
    try:
        return int(module.run(args) or 0)
    except (ValueError, FileNotFoundError, KeyError) as exc:
        # Bad input is the user's to fix: one clear line and a non-zero exit, no traceback.
        message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"plm-highway {words}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
