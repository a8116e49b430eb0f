"""`farm suite CONFIG --out DIR`: every policy on every scenario, on the same seeded episodes; a
leaderboard."""

from __future__ import annotations

import sys
from pathlib import Path

from farm.cli.options import add_cluster_options, flags
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm suite` and its flags to the `farm` parser's subcommands."""
    su = subparsers.add_parser("suite", help="every policy on every scenario, same seeded episodes: a leaderboard")
    su.add_argument("config", help="suite YAML, e.g. configs/suite.yaml")
    su.add_argument("--out", required=True, help="results folder (leaderboard.csv, episodes.csv, leaderboard.png, "
                                                 "suite.json)")
    su.add_argument("--episodes", type=int, help="override episodes (seeded seed .. seed+episodes-1)")
    su.add_argument("--games", type=int, help="override the capture-time service's games per case of every "
                                              "scenario (env: {games: N}; quick runs)")
    add_cluster_options(su, "evaluations running at once (default: the cluster's CPUs; a local Ray's CPUs)")
    su.set_defaults(func=run)


def run(args) -> int:
    """Run the suite into --out and print its leaderboard."""
    from farm.studies.suite import format_leaderboard, load_suite_config, run_suite

    for flag, least in (("episodes", 1), ("games", 2)):
        value = getattr(args, flag)
        if value is not None and value < least:
            raise CliError(f"--{flag}: must be >= {least}, got {value}")
    config = load_suite_config(args.config)
    if args.games is not None:
        config = config.model_copy(update={"env": {**config.env, "games": args.games}})
    out = Path(args.out)
    with flags("out", "address", "episodes", "workers", workers="num_cpus"):
        board, info = run_suite(config, out, episodes=args.episodes, address=args.address, workers=args.workers,
                                show_progress=not args.quiet)
    print(format_leaderboard(board))
    print(f"{config.name}: {info['tasks']} (scenario, policy) evaluations on {info['workers']} worker(s), "
          f"{info['warmed_cases']} lattice cases warmed in {info['warm_seconds']:.1f} s, evaluations "
          f"{info['evaluation_seconds']:.1f} s", file=sys.stderr)
    print(f"wrote {out / 'leaderboard.csv'}, episodes.csv, leaderboard.png, suite.json")
    return 0
