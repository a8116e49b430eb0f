"""The drift case against the worst case of `farm robust` runs' final meta-games: for each margin,
the allocators' mixture keeping at least the reference allocator's payoff against drift less the
margin with the best guaranteed value over the run's intruders (farm.studies.robust.frontier),
as a line a run, each allocator alone a point (named once, by the first run holding it); the table printed.

Usage: python tools/plot_drift_frontier.py OUT.png RUN_FOLDER [RUN_FOLDER ...]
           [--reference receding_horizon] [--against drift] [--margins 0 0.025 0.05 ...]
           [--mark 0.05] [--xmin X] [--write MARGIN]
Each RUN_FOLDER holds a run's robust.json and payoffs.csv (its final populations' payoffs on the
run's episodes); the worst case is over the run's intruders, an upper bound on the true one.
--write MARGIN writes each run's floored mixture at that margin as RUN_FOLDER/floored_MARGIN.yaml
(the allocator as the registry's `mixture`, for a `farm exploit` config).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

MARGINS = [0.0, 0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 1.0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("runs", type=Path, nargs="+", help="farm robust output folders")
    parser.add_argument("--reference", default="receding_horizon", help="the reference allocator, as tables show it")
    parser.add_argument("--against", default="drift", help="the intruder member of the drift case")
    parser.add_argument("--margins", type=float, nargs="+", default=MARGINS)
    parser.add_argument("--mark", type=float, default=0.05, help="a dashed line: the reference's drift less this")
    parser.add_argument("--write", type=float, default=None, help="write each run's floored mixture at this margin")
    parser.add_argument("--xmin", type=float, default=None, help="the figure's least drift case shown")
    parser.add_argument("--title", default="The drift case against the worst case")
    args = parser.parse_args()

    import pandas as pd
    import yaml
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from farm.studies.robust.frontier import drift_frontier, pure_points
    from farm.studies.robust.loop import STATE, Iteration, final_populations
    from farm.studies.robust.members import mixture_options

    fig = Figure(figsize=(7, 5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    named = set()
    for k, run in enumerate(args.runs):
        if not (run / STATE).exists() or not (run / "payoffs.csv").exists():
            print(f"runs: {run} holds no {STATE} and payoffs.csv", file=sys.stderr)
            return 2
        saved = json.loads((run / STATE).read_text())
        allocators, intruders = final_populations([Iteration.from_dict(d) for d in saved["iterations"]])
        table = pd.read_csv(run / "payoffs.csv", index_col=0)
        names, columns = [a.shown() for a in allocators], [b.shown() for b in intruders]
        M = table.loc[names, columns].to_numpy()
        for field, name, where in (("reference", args.reference, names), ("against", args.against, columns)):
            if name not in where:
                print(f"{field}: {name!r} is not in {run}'s populations", file=sys.stderr)
                return 2
        i, j = names.index(args.reference), columns.index(args.against)
        points = drift_frontier(M, i, j, args.margins)
        print(f"{run}: {args.reference} against {args.against} {M[i, j]:.3f}")
        print("| margin | floor | drift | worst | support |\n|---|---|---|---|---|")
        for p in points:
            support = ", ".join(f"{n} {w:.2f}" for n, w in zip(names, p["weights"]) if w > 1e-6)
            print(f"| {p['margin']:g} | {p['target']:.3f} | {p['drift']:.3f} | {p['worst']:.3f} | {support} |")
        line, = ax.plot([p["drift"] for p in points], [p["worst"] for p in points], "o-", label=f"{run.name}: mixtures")
        for (x, y), n in zip(pure_points(M, j), names):
            ax.plot(x, y, "x", color=line.get_color())
            if n not in named:  # each name once, by the first run holding it
                named.add(n)
                ax.annotate(n, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        if k == 0:
            ax.axvline(M[i, j] - args.mark, color="grey", linestyle="--", linewidth=1,
                       label=f"{args.reference} less {args.mark:g}")
        if args.write is not None:
            p = drift_frontier(M, i, j, [args.write])[0]
            spec = {"name": "mixture", "options": mixture_options(allocators, p["weights"]),
                    "label": f"{saved['name']}_floor{args.write:g}"}
            path = run / f"floored_{args.write:g}.yaml"
            path.write_text(yaml.safe_dump({"allocator": spec, "drift": p["drift"], "worst": p["worst"]},
                                           sort_keys=False))
            print(f"wrote {path}")
    if args.xmin is not None:
        ax.set_xlim(left=args.xmin)
    ax.set_xlabel(f"against {args.against}")
    ax.set_ylabel("worst over the run's intruders")
    ax.set_title(args.title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
