"""`farm robust CONFIG`: policy-space response oracles for the allocation game; each iteration's
NashConv and the final meta-Nash mixtures (resumable)."""

from __future__ import annotations

import sys
from pathlib import Path

from farm.cli.options import add_cluster_options, flags


def register(subparsers) -> None:
    """Add `farm robust` and its flags to the `farm` parser's subcommands."""
    rb = subparsers.add_parser("robust", help="allocators that hold against adapting intruders: policy-space "
                                              "response oracles on the farm (resumable)")
    rb.add_argument("config", help="robust YAML, e.g. configs/robust/outnumbered_3x3.yaml")
    rb.add_argument("--seed", type=int, help="the loop's seed instead of the config's; the name gets _s<seed> "
                                             "(make robust runs seeds 0, 1 and 2)")
    rb.add_argument("--out", help="results folder (default results/robust/NAME)")
    add_cluster_options(rb, "payoff rollouts and trials at once (default: the cluster's CPUs)")
    rb.set_defaults(func=run)


def run(args) -> int:
    """Run or resume the loop into --out and print each iteration's value, gains and NashConv."""
    from farm.studies.robust import load_robust_config, run_robust

    config = load_robust_config(args.config)
    if args.seed is not None:
        with flags("seed"):
            config = config.with_seed(args.seed)
    out = Path(args.out or f"results/robust/{config.name}")
    with flags("out", "address", "workers", workers="num_cpus"):
        iterations, info = run_robust(config, out, address=args.address, workers=args.workers,
                                      show_progress=not args.quiet)
    for k, it in enumerate(iterations):
        print(f"iteration {k}: {len(it.allocators)} allocators x {len(it.intruders)} intruder policies, value "
              f"{it.value:.4f}, gains {it.gains['defenders']:+.4f} (defenders) {it.gains['intruders']:+.4f} "
              f"(intruders), NashConv {it.nash_conv:.4f}")
    print(f"{config.name}: {len(iterations)} iteration(s) ({info['iterations_before']} before this run), "
          f"{info['pairs_played']} pairs played this time, {info['seconds']:.1f} s", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in info.get('files', []))}")
    return 0
