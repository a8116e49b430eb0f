"""`farm experiments CONFIG --out DIR`: trainings over a grid of settings and seeds as Ray Tune
trials on one capture-time service; trials.csv and summary.csv (resumable)."""

from __future__ import annotations

import sys
from pathlib import Path

from farm.cli.options import add_cluster_options, flags


def register(subparsers) -> None:
    """Add `farm experiments` and its flags to the `farm` parser's subcommands."""
    ex = subparsers.add_parser("experiments", help="trainings (TD3, PPO or SAC) over a grid of settings and seeds as "
                                                   "Ray Tune trials on one capture-time service (resumable)")
    ex.add_argument("config", help="experiments YAML, e.g. configs/experiments/smoke.yaml")
    ex.add_argument("--out", required=True, help="results folder (trials.csv, summary.csv, trials/, tune/), or an "
                                                 "object-store URI such as s3://bucket/path (no shared file system "
                                                 "needed on a cluster)")
    add_cluster_options(ex, "trials at once (default: the cluster's CPUs; a local Ray gets max(2, WORKERS) CPUs)")
    ex.set_defaults(func=run)


def run(args) -> int:
    """Run or resume the experiment into --out and print its summary."""
    from farm.studies.experiments import format_summary, load_experiment_config, run_experiment
    from farm.studies.experiments.storage import is_uri

    config = load_experiment_config(args.config)
    # a URI: the experiment in object storage (docs/experiments.md)
    out = args.out if is_uri(args.out) else Path(args.out)
    with flags("out", "address", "workers", workers="num_cpus"):
        trials, summary, info = run_experiment(config, out, source=str(args.config), address=args.address,
                                               workers=args.workers, show_progress=not args.quiet)
    print(format_summary(summary))
    print(f"{config.name}: {len(trials)}/{info['trials']} trial(s) finished "
          f"({info['finished_before']} before this run), "
          f"{info['workers']} at once at {info['trial_cpus']:g} CPU each on {info['cluster_cpus']:g} CPUs, "
          f"{info['warmed_cases']} lattice cases warmed in {info['warm_seconds']:.1f} s, "
          f"{info['seconds']:.1f} s in all", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in info['written'])}, trials/<trial>/run")
    return 0
