"""Density maps of an allocation episode (paper figures 6-9): defenders blue, intruders red."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _rgb(D: np.ndarray, I: np.ndarray) -> np.ndarray:
    """(N, N) densities -> (N, N, 3) float image: blue for defenders, red for intruders."""
    d = D / max(float(D.max()), 1e-12)
    i = I / max(float(I.max()), 1e-12) if I.max() > 0 else I
    img = np.ones(D.shape + (3,))
    img[..., 0] -= 0.85 * d
    img[..., 1] -= 0.85 * np.maximum(d, i)
    img[..., 2] -= 0.85 * i
    return np.clip(img, 0, 1)


def density_frame(D: np.ndarray, I: np.ndarray, step: int) -> np.ndarray:
    """One image of the densities for env.render(): defenders blue, intruders red.

    D, I: (N, N) float64 densities -> (32 N, 32 N, 3) uint8, each cell a 32 x 32 block.
    step: the env's step count, accepted for the caller and not drawn.
    """
    img = _rgb(D, I)
    scale = 32
    return (np.kron(img, np.ones((scale, scale, 1))) * 255).astype(np.uint8)


def plot_episode(frames: list[tuple[np.ndarray, np.ndarray]], path: str | Path, title: str = "") -> Path:
    """Save an episode's density maps to `path` (PNG): one panel per step, the masses written in.

    frames: one (D, I) pair per step, each (N, N) float64; title: above the panels when
    given. Returns the path.
    """
    from farm.plots import new_figure

    k = len(frames)
    fig, axes = new_figure(1, k, figsize=(2.4 * k, 2.9))
    for step, (ax, (D, I)) in enumerate(zip(axes[0], frames)):
        ax.imshow(_rgb(D, I), origin="upper")
        n = D.shape[0]
        for r in range(n):
            for c in range(n):
                text = []
                if D[r, c] > 0.005:
                    text.append(f"D {D[r, c]:.2f}")
                if I[r, c] > 0.005:
                    text.append(f"I {I[r, c]:.2f}")
                ax.text(c, r, "\n".join(text), ha="center", va="center", fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"step {step}", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    from farm.plots import save_figure

    return save_figure(fig, path)


def training_curve_figure(steps, results, title: str = ""):
    """The training curve: evaluation return (mean and spread over episodes) against environment steps.

    steps: (K,) int64 timesteps of the evaluations, results: (K, episodes) float64
    their returns (stable-baselines3's evaluations.npz) -> a matplotlib Figure (the
    mean, shaded one standard deviation either side).
    """
    from farm.plots import new_figure

    mean, std = results.mean(axis=1), results.std(axis=1)
    fig, axes = new_figure(figsize=(6, 3.6))
    ax = axes[0, 0]
    ax.plot(steps, mean, color="tab:blue", label="TD3 (deterministic eval)")
    ax.fill_between(steps, mean - std, mean + std, color="tab:blue", alpha=0.2)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return")
    if title:
        ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_training_curve(steps, results, path: Path, title: str) -> Path:
    """Save training_curve_figure(steps, results, title) to `path` (PNG); returns the path."""
    from farm.plots import save_figure

    return save_figure(training_curve_figure(steps, results, title), path)


def learning_curves_figure(curves, cols: int = 5):
    """An experiment's learning curves over seeds: one small panel per point, a grid of them.

    curves: a non-empty list of farm.experiments_results.PointCurves (timesteps (E,) int64,
    returns (S, E) float64) -> a matplotlib Figure. Each panel draws the mean over seeds as
    a line with its band shaded (farm.experiments_results.seed_band: the 95% CI over seeds,
    or the min-max of 2 seeds), titled with the point, its grid values, and the band's kind.
    cols: panels per row at most.
    """
    from farm.experiments_results import seed_band
    from farm.plots import new_figure

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
