"""NashConv and the meta-game's value by iteration of several `farm robust` runs (one line each, e.g.
one per seed) in one figure: the figure of docs/results.md's robust section.

Usage: python tools/plot_nash_conv.py OUT.png RUN_FOLDER [RUN_FOLDER ...] [--title TITLE]
Each RUN_FOLDER holds a run's nash_conv.csv; its line is labelled with the folder's name, and
beside it, dotted, NashConv with the intruders' exact half and the allocators' mixture's value
against the exact search, where the run has them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("runs", type=Path, nargs="+", help="farm robust output folders")
    parser.add_argument("--title", default="NashConv by iteration")
    args = parser.parse_args()

    import pandas as pd
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2))
    FigureCanvasAgg(fig)
    left, right = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    exact = False
    for run in args.runs:
        path = run / "nash_conv.csv"
        if not path.exists():
            print(f"runs: {run} holds no nash_conv.csv", file=sys.stderr)
            return 2
        rows = pd.read_csv(path)
        line, = left.plot(rows["iteration"], rows["nash_conv"], "o-", label=run.name)
        exact |= "exact_nash_conv" in rows or "exact_value" in rows
        if "exact_nash_conv" in rows:
            left.plot(rows["iteration"], rows["exact_nash_conv"], "^:", color=line.get_color(),
                      label=f"{run.name}, exact")
        right.plot(rows["iteration"], rows["value"], "s--", color=line.get_color(), label=run.name)
        if "exact_value" in rows:
            right.plot(rows["iteration"], rows["exact_value"], "^:", color=line.get_color(),
                       label=f"{run.name}, exact")
    left.set(xlabel="iteration", ylabel="NashConv", title=args.title)
    right.set(xlabel="iteration", ylabel="eliminated mass", title="the meta-game's value")
    if exact:
        left.text(0.01, -0.2, "dotted: with the intruders' exact best response", transform=left.transAxes,
                  fontsize=8)
        right.text(0.01, -0.2, "dotted: the allocators' mixture against the exact search", transform=right.transAxes,
                   fontsize=8)
    for ax in (left, right):
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
