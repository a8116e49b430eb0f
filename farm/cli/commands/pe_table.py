"""`farm pe-table`: the paper's Tables 1 and 2 by Monte Carlo games, with a figure a case."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from farm.cli.options import SPEED_FLAGS, add_game_options, checked_case, flags, game_settings
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm pe-table` and its flags to the `farm` parser's subcommands."""
    t = subparsers.add_parser("pe-table", help="the paper's Tables 1 and 2 with figures")
    t.add_argument("--games", type=int, default=50, help="Monte Carlo games per case")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", help="results folder (default results/pe-table; at other speeds "
                                 "results/pe-table-speeds-P-E)")
    t.add_argument("--format", choices=["csv", "parquet"], default="csv")
    t.add_argument("--no-figures", action="store_true")
    t.add_argument("--yes", action="store_true", help="run over the size limits (farm/games/sizes.py) anyway")
    add_game_options(t, SPEED_FLAGS)
    t.set_defaults(func=run)


def run(args) -> int:
    """Play the paper's cases at the speeds of the flags; print the tables and write them (and
    the figures) into --out."""
    from farm.core.output import check_writable_folder
    from farm.games.pe_table import (
        check_games,
        default_folder,
        format_tables,
        paper_speeds,
        pe_size,
        speeds_text,
        write_pe_tables,
    )
    from farm.games.sizes import check_size

    with flags("games"):
        check_games(args.games)
    base = checked_case({"n_pursuers": 1, "n_evaders": 1, **game_settings(args, SPEED_FLAGS)})
    check_size(pe_size(args.games, base), yes=args.yes, cpus=1)
    out = args.out or default_folder(base)
    if Path(out).exists() and not Path(out).is_dir():
        raise CliError(f"--out: {out} exists and is not a folder")
    with flags("out"):
        check_writable_folder(out, "out")  # before the games: a read-only --out is found now, not at the end
    t0 = time.perf_counter()
    written, summary = write_pe_tables(
        Path(out), args.games, args.seed, args.format, progress=lambda m: print("  " + m, file=sys.stderr),
        figures=not args.no_figures, base=base,
    )
    print(format_tables(summary))
    print("Our numbers come from the model of docs/model.md; the paper's evader target point and runs are unknown.")
    if not paper_speeds(base):
        print(f"These games ran at {speeds_text(base)}; the paper's figures are for equal speeds "
              "(1 and 1): a sensitivity check, not a fit.")
    for path in written:
        print(f"wrote {path}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
