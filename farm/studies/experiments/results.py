"""An experiment's learning curves over seeds, read back from its folder, finished or still
running: each point's periodic evaluation return (its trials' evaluations.npz), the mean over
its finished seeds with a band (farm.core.stats.seed_band), drawn as learning_curves.png.

A trial counts when it is finished (its result.json); finished trials of a point are aligned
on the evaluation timesteps they all have (the same ones, but for a point whose trials were
trained with other evaluation settings).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farm.alloc.training.runs import RunFolder
from farm.core.stats import seed_band
from farm.studies.experiment_folder import finished_trials, read_manifest

__all__ = ["PointCurves", "point_curves", "learning_curves_figure", "write_learning_curves", "LEARNING_CURVES"]

LEARNING_CURVES = "learning_curves.png"


@dataclass(frozen=True)
class PointCurves:
    """One point's learning curves over its finished seeds: point (its index), label (its grid
    values, `field=value` comma-separated), seeds (S,) ints, timesteps (E,) int64 (the
    evaluations every seed has) and returns (S, E) float64 (each seed's evaluation return,
    the mean over the evaluation's episodes)."""

    point: int
    label: str
    seeds: tuple[int, ...]
    timesteps: np.ndarray
    returns: np.ndarray


def point_curves(folder, manifest: dict) -> list[PointCurves]:
    """Every point with a finished, evaluated trial, in point order: its seeds' learning curves
    on the timesteps they all have (a point whose seeds share none is left out)."""
    by_point: dict[int, list[tuple[dict, np.ndarray, np.ndarray]]] = {}
    for t in finished_trials(folder, manifest):
        curve = RunFolder(t["run"]).evaluations()
        if curve is not None:
            steps, results = curve
            by_point.setdefault(t["point"], []).append((t, steps, results.mean(axis=1)))
    out = []
    for point, seeds in sorted(by_point.items()):
        common = seeds[0][1]
        for _, steps, _ in seeds[1:]:
            common = np.intersect1d(common, steps)
        if not len(common):
            continue
        returns = np.stack([means[np.searchsorted(steps, common)] for _, steps, means in seeds])
        values = seeds[0][0]["values"]
        label = ", ".join(f"{k}={v}" for k, v in values.items()) or "the base config"
        out.append(PointCurves(point=point, label=label, seeds=tuple(t["seed"] for t, _, _ in seeds),
                               timesteps=common, returns=returns))
    return out


def learning_curves_figure(curves, cols: int = 5):
    """An experiment's learning curves over seeds: one small panel per point, a grid of them.

    curves: a non-empty list of PointCurves (timesteps (E,) int64,
    returns (S, E) float64) -> a matplotlib Figure. Each panel draws the mean over seeds as
    a line with its band shaded (farm.core.stats.seed_band: the 95% CI over seeds,
    or the min-max of 2 seeds), titled with the point, its grid values, and the band's kind.
    cols: panels per row at most.
    """
    from farm.core.plots import new_figure

    cols = min(cols, len(curves))
    rows = -(-len(curves) // cols)
    fig, axes = new_figure(rows, cols, figsize=(2.9 * cols, 2.3 * rows + 0.4))
    for i, (ax, c) in enumerate(zip(axes.flat, curves)):
        mean, low, high, kind = seed_band(c.returns)
        ax.fill_between(c.timesteps, low, high, color="tab:blue", alpha=0.2, linewidth=0)
        ax.plot(c.timesteps, mean, color="tab:blue", linewidth=1.5)
        ax.set_title(f"p{c.point}: {c.label}\n{kind}", fontsize=7)
        ax.tick_params(labelsize=7)
        if i + cols >= len(curves):  # no panel below
            ax.set_xlabel("environment steps", fontsize=7)
        if i % cols == 0:
            ax.set_ylabel("evaluation return", fontsize=7)
    for ax in axes.flat[len(curves):]:
        ax.set_visible(False)
    fig.tight_layout()
    return fig


def write_learning_curves(folder) -> Path | None:
    """folder/learning_curves.png: the learning curves of every point over its finished seeds
    (learning_curves_figure); returns its path, None when no trial is finished."""
    from farm.core.plots import save_figure

    curves = point_curves(folder, read_manifest(folder))
    if not curves:
        return None
    return save_figure(learning_curves_figure(curves), Path(folder) / LEARNING_CURVES, dpi=90)
