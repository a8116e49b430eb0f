"""Figures: game trajectories over shaded Voronoi cells (paper figures 2-5)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, Polygon as PolygonPatch  # noqa: E402

from workers import GameResults  # noqa: E402

PURSUER_COLOR = "tab:blue"
EVADER_COLOR = "tab:red"


def save_figure(fig, path: str | Path, dpi: int = 100) -> Path:
    """Write fig to path (folders made as needed) and close it; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def default_frames(res: GameResults, game: int) -> list[int]:
    """Three frames: the start, half-way and the game's end (the last capture)."""
    end = int(res.steps[game])
    return sorted({0, end // 2, end})


def draw_game(ax, res: GameResults, game: int, frame: int) -> None:
    """One panel: cells at `frame` shaded, paths up to it, agents as markers."""
    n_p = res.pursuer_paths.shape[2]
    cells, agents = res.cells_at(frame, game)
    for c, agent in enumerate(agents):
        poly = cells.vertices[c, : cells.count[c]]
        color = PURSUER_COLOR if agent < n_p else EVADER_COLOR
        ax.add_patch(PolygonPatch(poly, closed=True, facecolor=color, alpha=0.12, edgecolor="0.4", lw=0.6))
    arena = np.vstack([res.arena.vertices, res.arena.vertices[:1]])
    ax.plot(arena[:, 0], arena[:, 1], color="k", lw=1.0)
    alive = res.alive_at(frame)[game]
    pp = res.pursuer_paths[: frame + 1, game]
    ep = res.evader_paths[: frame + 1, game]
    for j in range(n_p):
        ax.plot(pp[:, j, 0], pp[:, j, 1], color=PURSUER_COLOR, lw=0.8)
    for i in range(ep.shape[1]):
        ax.plot(ep[:, i, 0], ep[:, i, 1], color=EVADER_COLOR, lw=0.8)
    ax.scatter(pp[-1, :, 0], pp[-1, :, 1], marker="^", s=36, color=PURSUER_COLOR, zorder=3, label="pursuers")
    ax.scatter(
        ep[-1, alive, 0], ep[-1, alive, 1], marker="o", s=30, color=EVADER_COLOR, zorder=3, label="evaders"
    )
    escaped = np.zeros_like(alive) if res.escape_step is None else (res.escape_step[game] >= 0) & ~alive
    caught = ~alive & ~escaped
    if caught.any():
        ax.scatter(ep[-1, caught, 0], ep[-1, caught, 1], marker="x", s=30, color=EVADER_COLOR, zorder=3,
                   label="captured")
    if escaped.any():
        ax.scatter(ep[-1, escaped, 0], ep[-1, escaped, 1], marker="*", s=70, color="darkorange", zorder=4,
                   label="escaped")
    if res.exit_point is not None:
        ax.add_patch(Circle(res.exit_point, res.capture_radius, facecolor="none", edgecolor="darkorange", lw=1.2,
                            zorder=2, label="exit"))
    lo, hi = res.arena.vertices.min(axis=0), res.arena.vertices.max(axis=0)
    pad = 0.02 * float(np.max(hi - lo))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_title(f"t = {frame * res.dt:.2f} s")


def plot_game(res: GameResults, path: str | Path, *, game: int = 0, frames=None, title: str | None = None) -> Path:
    """Save a row of panels of one recorded game to `path` (PNG); returns the path."""
    if res.pursuer_paths is None:
        raise ValueError("plot_game needs results simulated with record=True")
    frames = default_frames(res, game) if frames is None else sorted(set(frames))
    fig, axes = plt.subplots(1, len(frames), figsize=(4.2 * len(frames), 4.4), squeeze=False)
    for ax, frame in zip(axes[0], frames):
        draw_game(ax, res, game, frame)
    axes[0][-1].legend(loc="upper right", fontsize=8)  # the last panel shows every kind of marker
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
