"""Figures of allocation: density maps of an episode (paper figures 6-9: defenders blue, intruders red),
the training curve, and the behaviour measures step by step."""

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
    from farm.core.plots import new_figure

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
    from farm.core.plots import save_figure

    return save_figure(fig, path)


def training_curve_figure(steps, results, title: str = ""):
    """The training curve: evaluation return (mean and spread over episodes) against environment steps.

    steps: (K,) int64 timesteps of the evaluations, results: (K, episodes) float64
    their returns (stable-baselines3's evaluations.npz) -> a matplotlib Figure (the
    mean, shaded one standard deviation either side).
    """
    from farm.core.plots import new_figure

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
    from farm.core.plots import save_figure

    return save_figure(training_curve_figure(steps, results, title), path)


def plot_behaviour_steps(means: dict[str, np.ndarray], path: Path) -> Path | None:
    """Coverage, engaged cells and defenders per engaged cell, step by step, one line per policy.

    means: {policy: (T, 3) float64 the step-by-step means (farm.alloc.evaluation.rollout.behaviour_pair)}.
    Returns path, or None for no policy."""
    from farm.core.plots import new_figure, save_figure

    if not means:
        return None
    fig, axes = new_figure(1, 3, figsize=(12, 3.2))
    axes = axes[0]
    titles = ("coverage (share of intruder mass met)", "engaged cells", "defenders per engaged cell")
    for name, m in means.items():
        for j, ax in enumerate(axes):
            ax.plot(np.arange(1, len(m) + 1), m[:, j], marker="o", label=name)
    for ax, title in zip(axes, titles):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
