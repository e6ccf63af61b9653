"""``plm-highway population``: K pairs trained with one recipe, each driven under the paper's settings, one report."""

from __future__ import annotations

from pathlib import Path

from plm_highway.cli._common import Command, add_device, bounded_int, static_names, static_value

DEFAULT_OUT = {"paper": Path("figures/population"), "ideal": Path("figures/population-ideal")}
DEFAULT_WORK = Path("runs/population")


def configure(parser) -> None:
    from plm_highway.rollout.backends import BACKENDS, MAX_WORKERS, default_workers

    # Read from the library's source, not imported: the help page imports no torch (tests/test_cli_help.py).
    DEFAULT_SIM_SEEDS, MAX_PAIRS = (static_value("plm_highway.population.plan", name)
                                    for name in ("DEFAULT_SIM_SEEDS", "MAX_PAIRS"))
    RECIPES = static_names("plm_highway.population.recipe", "RECIPES")
    REMEDIES = static_value("plm_highway.population.remedies", "REMEDIES")
    CONDITION_NAMES = static_names("plm_highway.rollout.conditions", "CONDITION_NAMES")
    LATENCY_SOURCE_NAMES = static_value("plm_highway.rollout.conditions", "LATENCY_SOURCE_NAMES")

    parser.add_argument("--pairs", type=bounded_int(1, MAX_PAIRS), required=True,
                        help="how many BM/TAPM pairs to train (pair k: data seed 1+k, training seeds k)")
    parser.add_argument("--conditions", choices=CONDITION_NAMES, default="paper",
                        help="closed-loop conditions (and the recipe made for them)")
    parser.add_argument("--recipe", choices=tuple(RECIPES),
                        help="the documented recipe every pair is made with (default: the conditions' shipped one)")
    parser.add_argument("--remedy", action="append", default=[], choices=tuple(REMEDIES),
                        help="also try this TAPM remedy on the same pairs (repeatable): " + "; ".join(
                            f"{name}: {text}" for name, text in REMEDIES.items()))
    parser.add_argument("--track", default="test", help="track the pairs are judged on")
    parser.add_argument("--latency-source", choices=LATENCY_SOURCE_NAMES,
                        help="what PLM-Net is told of the latency (default: the conditions' own); 'estimated': the "
                             "latency estimated from the stream, logged beside the true age")
    parser.add_argument("--seeds", default=str(DEFAULT_SIM_SEEDS), metavar="N|LIST",
                        help="simulator seeds per pair and setting: a count (5: seeds 0-4) or a list")
    parser.add_argument("--out", type=Path,
                        help="report directory (default: figures/population, figures/population-ideal for ideal)")
    parser.add_argument("--work", type=Path, help="work directory with checkpoints and per-run results; run again "
                                                  "with the same options to resume (default: runs/population/"
                                                  "CONDITIONS)")
    shrink = parser.add_argument_group("quick runs (a population made with these is labelled as not the recipe's)")
    shrink.add_argument("--episodes", type=bounded_int(1, 100_000), help="demonstration episodes per pair")
    shrink.add_argument("--max-samples", type=bounded_int(2, 10**9), help="training samples of each model")
    shrink.add_argument("--epochs", type=bounded_int(1, 1000), help="training epochs of each model")
    shrink.add_argument("--max-steps", type=bounded_int(1, 10_000_000), help="stop each run after this many steps")
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local: a process pool on this machine; ray: a Ray cluster (pip install ray)")
    parser.add_argument("--workers", type=bounded_int(0, MAX_WORKERS), default=default_workers(),
                        help="processes (local) or CPUs of a private local Ray; 0: everything in this process")
    parser.add_argument("--address", help="with --backend ray: a running cluster (HOST:PORT or auto)")
    parser.add_argument("--batch-size", type=bounded_int(1, 4096), default=16,
                        help="envs stepped together per worker (one batched forward pass per step)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--report-only", action="store_true",
                        help="render the report from the pairs committed under --out; train and drive nothing "
                             "(no --work is made or read)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an earlier population report at --out (never anything else)")
    parser.add_argument("--restart", action="store_true",
                        help="start the work directory afresh instead of resuming it (its checkpoints are lost)")
    add_device(parser)


def run(args) -> int:
    from plm_highway.population.plan import make_plan
    from plm_highway.population.recipe import recipe_named, with_overrides
    from plm_highway.population.report import headline
    from plm_highway.population.study import RunOptions, run_population
    from plm_highway.rollout.seeds import parse_seeds

    recipe = with_overrides(recipe_named(args.recipe, args.conditions), args.episodes, args.max_samples, args.epochs)
    plan = make_plan(recipe, args.conditions, args.pairs, args.track, sim_seeds=tuple(parse_seeds(args.seeds)),
                     max_steps=args.max_steps, remedies=tuple(args.remedy), latency_source=args.latency_source)
    out = args.out or DEFAULT_OUT[args.conditions]
    work = args.work or DEFAULT_WORK / args.conditions
    if args.backend != "ray":  # a Ray worker resolves auto/cuda itself: its machine may have the GPU
        from plm_highway.models.device import resolve_device

        resolve_device(args.device)
    options = RunOptions(work, out, args.backend, args.workers, args.address, args.batch_size, args.overwrite,
                         args.restart, not args.no_progress, args.report_only, args.command_line, args.device)
    result = run_population(plan, options)
    document = {"plan": plan.as_dict(), **result}
    for line in headline(document):
        print(line)
    print(f"report: {out / 'report.md'}")
    return 0


COMMANDS = [Command("population", "train K BM/TAPM pairs with one recipe and judge PLM-Net across them, on the lane "
                    "and on the steering (resumable; process pool or Ray)", configure, run)]
