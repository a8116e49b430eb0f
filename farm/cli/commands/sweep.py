"""`farm sweep CONFIG`: run or resume a parametric Monte Carlo sweep; prints its summary."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from farm.cli.options import flags, refuse_contradictions
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm sweep` and its flags to the `farm` parser's subcommands."""
    s = subparsers.add_parser("sweep", help="run a parametric Monte Carlo sweep on Ray or in this process (resumable)")
    s.add_argument("config", help="sweep YAML, e.g. configs/smoke.yaml")
    s.add_argument("--out", help="results folder (default results/sweeps/<name>)")
    s.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    s.add_argument("--workers", type=int, help="shards running at once (default: the cluster's CPUs)")
    s.add_argument("--metrics-port", type=int, help="local Ray only: Prometheus export port")
    s.add_argument("--no-ray", action="store_true", help="run the shards in this process, without Ray")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--yes", action="store_true", help="run a sweep over the size limits (farm/games/sizes.py) anyway")
    s.add_argument("--rebuild", action="store_true",
                   help="write a damaged or missing OUT/sweep.json again from CONFIG (its shards' sweep id is checked)")
    s.set_defaults(func=run)


def run(args) -> int:
    """Run the sweep of CONFIG into --out and print its summary; CliError for flags that
    contradict each other or a metrics port a local Ray cannot export on."""
    from farm.games.sweep import format_summary, load_sweep_config, print_info, run_sweep

    no_ray = True if args.no_ray else None
    refuse_contradictions(argparse.Namespace(no_ray=no_ray, address=args.address, workers=args.workers,
                                             metrics_port=args.metrics_port),
                          [("no_ray", "address"), ("no_ray", "workers"), ("no_ray", "metrics_port"),
                           ("address", "metrics_port")])
    if args.metrics_port is not None and not 1 <= args.metrics_port <= 65535:
        raise CliError(f"--metrics-port: must be a TCP port from 1 to 65535, got {args.metrics_port}")
    if args.metrics_port is not None and os.environ.get("RAY_ADDRESS"):
        raise CliError("--metrics-port: is for a local Ray, but RAY_ADDRESS names a cluster to join")
    config = load_sweep_config(args.config)
    out = Path(args.out) if args.out else Path("results") / "sweeps" / config.name
    with flags("out", "address", "metrics_port", "rebuild", "workers", workers="num_cpus"):
        summary, info = run_sweep(config, out, address=args.address, workers=args.workers, use_ray=not args.no_ray,
                                  show_progress=not args.quiet, metrics_port=args.metrics_port, yes=args.yes,
                                  rebuild=args.rebuild)
    print_info(info)
    print(f"{config.name}: {len(summary)} point(s), {int(summary['n_games'].sum())} games")
    print(format_summary(summary, config.vary.names()))
    print(f"results: {out}/summary.parquet, {out}/summary.csv, {out}/shards/")
    return 0
