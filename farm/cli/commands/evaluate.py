"""`farm eval RUN_DIR`: the trained allocator, the baselines and the planners on the same seeded
episodes."""

from __future__ import annotations

from pathlib import Path

from farm.cli.options import flags
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm eval` and its flags to the `farm` parser's subcommands."""
    ev = subparsers.add_parser("eval", help="the trained policy against the baselines and the planners on the same "
                                            "seeded episodes")
    ev.add_argument("run_dir")
    ev.add_argument("--episodes", type=int, default=20)
    ev.add_argument("--seed", type=int, default=1000)
    ev.add_argument("--fidelity", choices=["service", "games"], default="service")
    ev.add_argument("--quiet", action="store_true", help="no progress bar (--fidelity games)")
    ev.add_argument("--animate", nargs="?", const="episode.gif", metavar="PATH",
                    help="also animate the trained allocator's first episode (.gif or .mp4, in the run folder; "
                         "default episode.gif); under --fidelity games with one engaged cell's game beside it")
    ev.add_argument("--scenario", help="evaluate on this suite scenario's map instead of the run's own (a CellPolicy "
                                       "acts on any map size); files go to RUN_DIR/scenarios/NAME/")
    ev.add_argument("--references", help="the baselines and planners to compare with, comma-separated, or 'none' "
                                         "(default: every one)")
    ev.add_argument("--repair", help="the trained allocator's output: 'none' (its network alone) or 'levels' "
                                     "(the level repair); default: the run's config's. Another than the run's "
                                     "own writes into repair_<value>/")
    ev.set_defaults(func=run)


def run(args) -> int:
    """Evaluate the run folder and print its tables (and the games' under --fidelity games)."""
    from farm.alloc.evaluation.evaluate import evaluate_run, fidelity_lines

    run_dir = Path(args.run_dir)
    references = None if args.references is None else _references(args.references)
    with flags("episodes", "seed", "fidelity", "scenario", "references", "repair"):
        result = evaluate_run(run_dir, episodes=args.episodes, seed=args.seed, fidelity=args.fidelity,
                              scenario=args.scenario, references=references, animate=args.animate,
                              show_progress=not args.quiet, repair=args.repair)
    run_dir = result.folder
    print(result.table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    if result.games_table is not None:
        print("\n--fidelity games (every engaged cell's game simulated each step):")
        print(result.games_table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
        for line in fidelity_lines(result):
            print(line)
    print(f"wrote {run_dir / 'eval_table.csv'}, eval_episodes.csv, eval_steps.csv, behaviour_steps.png and "
          "density maps density_<policy>.png")
    if result.animation is not None:
        print(f"animation: {result.animation[0]} ({result.animation[1]} frames)")
    return 0


def _references(text: str) -> list[str]:
    """--references' names: `none` alone for none; CliError for an empty entry, a name given
    twice, or `none` beside names (which it would contradict)."""
    names = [n.strip() for n in text.split(",")]
    if any(not n for n in names):
        raise CliError(f"--references: an empty entry in {text!r}")
    if "none" in names and len(names) > 1:
        other = next(n for n in names if n != "none")
        raise CliError(f"--references: 'none' and {other!r} contradict each other; give none alone, or the names")
    twice = next((n for k, n in enumerate(names) if n in names[:k]), None)
    if twice is not None:
        raise CliError(f"--references: {twice!r} is named twice")
    return [] if names == ["none"] else names
