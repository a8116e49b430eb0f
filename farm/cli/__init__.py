"""The `farm` command line: `main`, and its parser built from COMMANDS, one module a command
(farm/cli/commands/, each with `register(subparsers)` and `run(args)`); the flags and parsing
they share are farm/cli/options.py. Bad input ends in one line `farm: error: ...`, exit 2."""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from workers import SwarmFarmError

from farm.cli.commands import (
    claims,
    evaluate,
    experiments,
    exploit,
    game,
    pe_table,
    report,
    robust,
    suite,
    sweep,
    table,
    train,
)
from farm.cli.options import Parser, join_negative_values, one_line_warning, ray_errors, refuse_empty_values

__all__ = ["main", "build_parser", "COMMANDS", "DEBUG_ENV"]

COMMANDS = (game, pe_table, sweep, table, report, train, evaluate, suite, experiments, exploit, robust, claims)
DEBUG_ENV = "SWARM_FARM_DEBUG"


def build_parser() -> argparse.ArgumentParser:
    """The `farm` argument parser: a subcommand for each of COMMANDS, in their order."""
    parser = Parser(prog="farm", description="swarm-farm: swarm-to-swarm engagement planning and learning")
    parser.add_argument("--debug", action="store_true",
                        help=f"show the traceback of an error (also {DEBUG_ENV}=1)")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for command in COMMANDS:
        command.register(subparsers)
    return parser


def main(argv=None) -> int:
    """Run the `farm` command line; returns the exit status (2 for bad input, one line on stderr).
    `farm --debug ...` (the flag anywhere) or SWARM_FARM_DEBUG=1 lets errors through with their traceback."""
    argv = join_negative_values(sys.argv[1:] if argv is None else [str(x) for x in argv])
    debug = os.environ.get(DEBUG_ENV, "") not in ("", "0") or "--debug" in argv
    argv = [x for x in argv if x != "--debug"]  # --debug is taken before or after the subcommand
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.showwarning = one_line_warning  # restored when the block ends
            parser = build_parser()
            args = parser.parse_args(argv)
            refuse_empty_values(parser, args)
            return args.func(args)
    except KeyboardInterrupt:
        if debug:
            raise
        print("farm: interrupted", file=sys.stderr)
        return 130
    except SwarmFarmError as e:
        if debug:
            raise
        print(f"farm: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a file or folder the user named, or a cluster that does not answer
        if debug:
            raise
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"farm: error: {where}{e.strerror or str(e).splitlines()[0] or type(e).__name__}", file=sys.stderr)
        return 2
    except ray_errors() as e:  # a Ray failure: its cause, in one line
        if debug:
            raise
        cause = getattr(e, "cause", None) or e
        text = str(cause).strip().splitlines()
        print(f"farm: error: Ray: {type(cause).__name__}: {text[-1] if text else ''}", file=sys.stderr)
        return 2
