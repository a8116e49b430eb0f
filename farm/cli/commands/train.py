"""`farm train CONFIG`: train a learner (TD3, PPO or SAC) into a run folder; prints its metrics."""

from __future__ import annotations

import json
from pathlib import Path

from workers import SwarmFarmError

from farm.cli.options import flags
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm train` and its flags to the `farm` parser's subcommands."""
    tr = subparsers.add_parser("train", help="train an allocator, or the intruders against a frozen one, with TD3, "
                                             "PPO or SAC (rewards from the capture-time service)")
    tr.add_argument("config", help="training YAML, e.g. configs/train/paper_3x3_c1_0.yaml")
    tr.add_argument("--out", help="run folder (default results/runs/<name>)")
    tr.add_argument("--resume", action="store_true", help="go on from the run folder's last checkpoint")
    tr.add_argument("--timesteps", type=int, help="override the learner's n_timesteps (td3.n_timesteps, "
                                                  "ppo.n_timesteps or sac.n_timesteps)")
    tr.add_argument("--service", choices=["ray", "local"], help="override service.mode")
    tr.add_argument("--threads", type=int, help="override threads: torch threads while training (config default 1)")
    tr.add_argument("--quiet", action="store_true")
    tr.set_defaults(func=run)


def run(args) -> int:
    """Train the config, with the flags' overrides, into --out and print the run's metrics."""
    from farm.alloc.training import load_train_config, train

    config = load_train_config(args.config, trainable=False)  # checked below, with --timesteps applied
    if args.timesteps is not None:
        if args.timesteps < 1:
            raise CliError(f"--timesteps: must be >= 1, got {args.timesteps}")
        starts = getattr(config.learner, "learning_starts", None)
        if starts is not None and args.timesteps <= starts:
            raise CliError(f"--timesteps: {args.timesteps} steps, but {config.algo}.learning_starts is {starts}: "
                           f"the model would never be updated")
        config = config.with_timesteps(args.timesteps)
    from farm.alloc.training.config import check_trainable

    try:
        check_trainable(config)  # with --timesteps applied: its own check above named the flag
    except SwarmFarmError as e:
        raise CliError(f"{args.config}: {e}") from None
    if args.service:
        config = config.model_copy(update={"service": config.service.model_copy(update={"mode": args.service})})
    if args.threads is not None:
        if args.threads < 1:
            raise CliError(f"--threads: must be >= 1, got {args.threads}")
        config = config.model_copy(update={"threads": args.threads})
    out = Path(args.out or Path("results") / "runs" / config.name)
    with flags("out", "resume"):
        metrics = train(config, out, resume=args.resume, show_progress=not args.quiet)
    print(json.dumps(metrics, indent=2))
    print(f"run: {out}")
    return 0
