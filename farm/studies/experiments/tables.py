"""An experiment's tables: trials.csv (one row per finished trial), summary.csv (one row per
point, means and 95% CIs over seeds) and the summary as shown (docs/experiments.md lists the columns)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from farm.core.stats import ci_columns, format_ci
from farm.studies.experiment_folder import ExperimentFolder
from farm.studies.experiments.plan import Plan

__all__ = ["LEARNED", "trials_table", "summary_table", "summary_view", "format_summary", "manifest_trials",
           "TIMING_COLUMNS", "METRICS_COLUMNS"]

TIMING_COLUMNS = ("wall_seconds", "steps_per_second", "update_seconds", "outside_update_share", "train_seconds",
                  "evaluate_seconds")
LEARNED = "learned"  # trials.csv's prefix of the trained allocator's columns (its algo in column `algo`)
OLD_LEARNED = "td3"  # the prefix of an older trial's columns, without `algo`
METRICS_COLUMNS = ("timesteps", "resumed_from", "engagements", "estimated_share", *TIMING_COLUMNS[:4],
                   "pretrain_states", "pretrain_seconds")


def manifest_trials(plan: Plan) -> list[dict]:
    """experiment.json's list of trials: {key, point, seed, values} each, in grid order."""
    return [{"key": t.key, "point": t.point, "seed": t.seed, "values": t.values} for t in plan.trials]


def trials_table(plan: Plan, out: Path) -> pd.DataFrame:
    """trials.csv (docs/experiments.md) from the trials' result.json files, in grid order; a
    trial without one (not finished) is left out."""
    return pd.DataFrame([t["result"] for t in ExperimentFolder(out).finished_trials({"trials": manifest_trials(plan)})])


def summary_table(fields: list[str], trials: pd.DataFrame) -> pd.DataFrame:
    """summary.csv (docs/experiments.md): one row per point with finished trials; fields: the
    grid's dotted fields (Plan.fields), trials: trials.csv's table."""
    if trials.empty:
        return pd.DataFrame()
    learned = LEARNED if f"{LEARNED}_return" in trials.columns else OLD_LEARNED  # before `algo`: td3's columns
    others = [c[: -len("_return")] for c in trials.columns
              if c.endswith("_return") and c not in (f"{learned}_return", "final_eval_return", "best_eval_return")]
    rows = []
    for point, g in trials.groupby("point", sort=True):
        row = {"point": int(point), **{f: g[f].iloc[0] for f in fields}, "seeds": len(g)}
        if "algo" in g and "algo" not in fields:
            row["algo"] = g["algo"].iloc[0]
        row.update(ci_columns({name: g[col].to_numpy(dtype=float) for name, col in (
            ("return", f"{learned}_return"), ("eliminated", f"{learned}_eliminated"),
            ("final_eval_return", "final_eval_return"))}))
        for name in others:
            row[f"{name}_return"] = float(g[f"{name}_return"].mean())
            row[f"{name}_eliminated"] = float(g[f"{name}_eliminated"].mean())
        rows.append(row)
    return pd.DataFrame(rows)


def summary_view(summary: pd.DataFrame) -> pd.DataFrame:
    """summary.csv as shown (format_summary, farm report): point, the point's fields, seeds,
    the learner's return and eliminated as `mean ± CI` strings, and the baseline or planner eliminating
    the most (`name value`); an empty frame for an empty summary."""
    if summary.empty:
        return pd.DataFrame()
    fields = list(summary.columns[1: list(summary.columns).index("seeds") + 1])
    view = summary[["point", *fields]].copy()
    view["learned return"] = [format_ci(m, h) for m, h in zip(summary["return_mean"], summary["return_ci95"])]
    view["learned eliminated"] = [format_ci(m, h) for m, h in zip(summary["eliminated_mean"],
                                                                     summary["eliminated_ci95"])]
    others = [c[: -len("_eliminated")] for c in summary.columns if c.endswith("_eliminated")]
    if others:
        best = [max(others, key=lambda n: r[f"{n}_eliminated"]) for _, r in summary.iterrows()]
        view["best other (eliminated)"] = [f"{n} {r[f'{n}_eliminated']:.3f}"
                                           for n, (_, r) in zip(best, summary.iterrows())]
    return view


def format_summary(summary: pd.DataFrame) -> str:
    """summary.csv as a text table (summary_view)."""
    if summary.empty:
        return "(no finished trials)"
    return summary_view(summary).to_string(index=False)
