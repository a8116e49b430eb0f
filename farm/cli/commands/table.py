"""`farm table [show] CONFIG`: fill the capture-time store over a table's cells, or show it."""

from __future__ import annotations

from pathlib import Path

from farm.cli.options import flags, refuse_contradictions
from farm.core.errors import CliError


def register(subparsers) -> None:
    """Add `farm table` and its flags to the `farm` parser's subcommands."""
    tb = subparsers.add_parser("table", help="fill the capture-time store (farm table CONFIG) or show it "
                                             "(farm table show CONFIG)")
    tb.add_argument("args", nargs="+", metavar="[show] CONFIG")
    tb.add_argument("--store", help="SQLite store (default: the config's `store`)")
    tb.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    tb.add_argument("--workers", type=int, help="local Ray only: CPUs")
    tb.add_argument("--plot-dir", help="where heatmaps go (default: next to the store, tables/)")
    tb.add_argument("--quiet", action="store_true")
    tb.add_argument("--yes", action="store_true", help="fill a table over the size limits (farm/games/sizes.py) anyway")
    tb.set_defaults(func=run)


def run(args) -> int:
    """Fill the store over the table's cells (not with `show`), then print each policy pair's
    mean capture times and captured fractions and write their heatmaps."""
    from farm.service.table import fill_table, load_table_config, plot_heatmaps, table_frames

    words = list(args.args)
    show = bool(words) and words[0] == "show"
    if show:
        words = words[1:]
    if len(words) != 1:
        raise CliError("table: usage: farm table CONFIG | farm table show CONFIG")
    if show:
        for flag in ("address", "workers", "yes"):
            if getattr(args, flag) not in (None, False):
                raise CliError(f"--{flag}: `farm table show` only reads the store; --{flag} is for `farm table`")
    refuse_contradictions(args, [("address", "workers")])
    config = load_table_config(words[0])
    if not show:
        from farm.games.sizes import check_size
        from farm.runtime import check_workers

        with flags("store", "address", "workers", workers="num_cpus"):
            check_workers(args.workers)
            check_size(config.size(), yes=args.yes, cpus=args.workers or 2)
            info = fill_table(config, store=args.store, address=args.address, workers=args.workers,
                              show_progress=not args.quiet)
        print(f"{config.name}: {info['cases']} cases, {info['computed']} computed, the rest from the store "
              f"({info['seconds']:.1f} s)")
    out = Path(args.plot_dir or config.store_path(args.store).parent / "tables")
    for settings, mean, frac in table_frames(config, store=args.store):
        print(f"\n{settings.game.pursuer_policy} vs {settings.game.evader_policy}: mean capture time (s)")
        print(mean.to_string(float_format=lambda x: f"{x:.2f}", na_rep="-"))
        print(f"fraction of evaders captured within tau = {settings.game.tau:g} s")
        print(frac.to_string(float_format=lambda x: f"{x:.2f}", na_rep="-"))
        name = f"{config.name}_{settings.game.pursuer_policy}_vs_{settings.game.evader_policy}.png"
        print(f"heatmaps: {plot_heatmaps(settings, mean, frac, out / name)}")
    return 0
