"""The suite's leaderboard: one row per (scenario, allocator) of its episodes (leaderboard), the
chart of the intruder mass eliminated (plot_leaderboard) and the text table (leaderboard_view,
format_leaderboard; farm report shows the same view)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from farm.alloc.evaluation.rollout import measure_table
from farm.core.stats import format_ci

__all__ = ["MEASURES", "leaderboard", "worst_cases", "plot_leaderboard", "leaderboard_view", "format_leaderboard"]

MEASURES = ("return", "eliminated", "breached", "coverage")  # of farm.alloc.game.measures.MEASURES: the board's columns


def leaderboard(per: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, policy) of the per-episode rows, in their order of appearance; one per
    (scenario, intruders, policy) when per has an `intruders` column (a suite's adversary axis).

    per: episodes.csv's columns (scenario, [intruders,] policy, return, eliminated, breached,
    coverage, steps, predict_seconds, ...). Returns columns scenario, [intruders,] policy,
    episodes, <m>_mean and <m>_ci95 for each m of MEASURES (farm.alloc.evaluation.rollout.measure_table:
    the 95% t interval over episodes; NaN half-width for one episode), seconds_per_step (predict
    seconds over steps); with the axis also worst_eliminated and worst_intruders, the lowest
    eliminated mass of the (scenario, policy) over the intruder policies and the one that
    reached it (on each of its rows).
    """
    by = ["scenario", "intruders", "policy"] if "intruders" in per.columns else ["scenario", "policy"]
    board = measure_table(per, by, MEASURES)
    seconds = []
    for _, g in per.groupby(by, sort=False):
        steps = int(g["steps"].sum())
        seconds.append(float(g["predict_seconds"].sum()) / steps if steps else math.nan)
    board["seconds_per_step"] = seconds
    if "intruders" in per.columns:
        worst = board.loc[board.groupby(["scenario", "policy"], sort=False)["eliminated_mean"].idxmin()]
        worst = worst.set_index(["scenario", "policy"])
        keys = list(zip(board["scenario"], board["policy"]))
        board["worst_eliminated"] = [worst.loc[k, "eliminated_mean"] for k in keys]
        board["worst_intruders"] = [worst.loc[k, "intruders"] for k in keys]
    return board


def worst_cases(board: pd.DataFrame) -> pd.DataFrame:
    """A board with an adversary axis as one row per (scenario, policy): its worst intruder policy's
    row (the leaderboard's columns, the intruders named)."""
    return board.loc[board.groupby(["scenario", "policy"], sort=False)["eliminated_mean"].idxmin()].reset_index(
        drop=True)


def plot_leaderboard(board: pd.DataFrame, path, title: str = "intruder mass eliminated") -> Path:
    """The intruder mass eliminated per scenario, one bar per policy, 95% CI error bars; returns path.

    board: leaderboard()'s columns (scenario, policy, eliminated_mean, eliminated_ci95); with an
    adversary axis, each (scenario, policy)'s worst case is drawn.
    """
    if "intruders" in board.columns:
        board = worst_cases(board)
        title = f"{title} against the worst intruder policy"
    from farm.core.plots import new_figure, save_figure

    scenarios = list(dict.fromkeys(board["scenario"]))
    policies = list(dict.fromkeys(board["policy"]))
    width = 0.8 / len(policies)
    fig, axes = new_figure(figsize=(min(24.0, max(7.0, 3.0 + len(scenarios) * (0.3 + 0.16 * len(policies)))), 4.2))
    ax = axes[0, 0]
    colours = [f"C{k % 10}" for k in range(len(policies))]
    for k, policy in enumerate(policies):
        g = board[board["policy"] == policy].set_index("scenario").reindex(scenarios)
        x = np.arange(len(scenarios)) + (k - (len(policies) - 1) / 2) * width
        err = np.nan_to_num(g["eliminated_ci95"].to_numpy(dtype=float))
        ax.bar(x, g["eliminated_mean"].to_numpy(dtype=float), width, yerr=err, capsize=2, label=policy,
               color=colours[k])
    ax.set_xticks(range(len(scenarios)), scenarios, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("intruder mass eliminated")
    ax.set_ylim(0, 1.05)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
    fig.tight_layout()
    return save_figure(fig, path)


def leaderboard_view(board: pd.DataFrame, coverage: bool = False, ms_label: str = "ms/step") -> pd.DataFrame:
    """The leaderboard as shown: scenario, policy, episodes, eliminated, breached and return
    (and coverage) as `mean ± CI` (format_ci), and the milliseconds per decision."""
    shown = ["eliminated", "breached", "return", *(["coverage"] if coverage else [])]
    axis = {"intruders": board["intruders"]} if "intruders" in board.columns else {}
    view = pd.DataFrame({"scenario": board["scenario"], **axis, "policy": board["policy"],
                         "episodes": board["episodes"],
                         **{m: [format_ci(x, h) for x, h in zip(board[f"{m}_mean"], board[f"{m}_ci95"])]
                            for m in shown}})
    if axis:
        view["worst case"] = [f"{w:.3f} ({i})" for w, i in zip(board["worst_eliminated"], board["worst_intruders"])]
    view[ms_label] = [f"{1000 * s:.2f}" for s in board["seconds_per_step"]]
    return view


def format_leaderboard(board: pd.DataFrame) -> str:
    """The leaderboard as a text table (leaderboard_view)."""
    return leaderboard_view(board).to_string(index=False)
