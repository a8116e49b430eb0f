"""Figures: game trajectories over shaded Voronoi cells (paper figures 2-5), heatmaps,
and the one way every figure of the project is made and saved.

Figures are matplotlib `Figure` objects drawn without pyplot, so no backend is chosen
and no global state is touched: a user's own matplotlib setup is left as it is.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.patches import Polygon as PolygonPatch

from workers import GameResults

from farm.core.errors import ConfigError

PURSUER_COLOR = "tab:blue"
EVADER_COLOR = "tab:red"


def new_figure(rows: int = 1, cols: int = 1, figsize=(6, 4)):
    """A new Figure and its panels, made without pyplot (no backend, no global state).

    Returns (Figure, axes): axes a (rows, cols) object array of Axes, 2-D even for one panel.
    """
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, cols, squeeze=False)


def save_figure(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Write a figure to a file, its format from the suffix; returns the path.

    The path's folders are made as needed; dpi: the resolution of raster formats.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def figure_png(fig: Figure, dpi: int = 100) -> bytes:
    """A figure as PNG bytes (for pages that inline their images)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def draw_heatmap(fig: Figure, ax, grid: pd.DataFrame, title: str, cmap: str = "viridis") -> None:
    """Draw one statistic over team sizes as a heatmap on ax, with a colour bar on fig.

    grid: a DataFrame indexed by n_pursuers (rows, drawn bottom up) with one column per
    n_evaders, the statistic's values (NaN: blank); title: above the panel.
    """
    im = ax.imshow(grid.to_numpy(dtype=float), origin="lower", aspect="auto", cmap=cmap)
    ax.set_xticks(range(len(grid.columns)), [str(c) for c in grid.columns])
    ax.set_yticks(range(len(grid.index)), [str(i) for i in grid.index])
    ax.set_xlabel("evaders n_e")
    ax.set_ylabel("pursuers n_p")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax)


def default_frames(res: GameResults, game: int) -> list[int]:
    """The frames plot_game draws by default: the start, half-way and the game's end.

    The end is the step the game ended at (its last capture or escape, else t_max);
    returns the sorted distinct step indices.
    """
    end = int(res.steps[game])
    return sorted({0, end // 2, end})


def frames_at(res: GameResults, times, game: int = 0, field: str = "times") -> list[int]:
    """The step indices of one recorded game at `times` (s), a time past the game's end at its
    end; ConfigError naming field unless every time is finite and >= 0."""
    if not all(np.isfinite(t) and t >= 0 for t in times):
        raise ConfigError(f"{field}: times must be finite and >= 0", field=field)
    return [min(int(round(t / res.dt)), int(res.steps[game])) for t in times]


def draw_game(ax, res: GameResults, game: int, frame: int) -> None:
    """Draw one panel of a recorded game at a frame (a step index) on ax.

    The agents' Voronoi cells at `frame` shaded (pursuers blue, evaders red), paths up to
    it, pursuers as triangles, live evaders as dots, captured ones as crosses, escaped
    ones as stars, and the exit point's circle when the game has one. res: recorded with
    record=True; game: its index in res.
    """
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
    escaped = (res.escape_step[game] >= 0) & ~alive
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


FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def check_figure_path(path, field: str = "plot") -> Path:
    """path as a Path when it names a .png, .pdf or .svg file, else ConfigError naming field."""
    if Path(path).suffix.lower() not in FIGURE_SUFFIXES:
        raise ConfigError(f"{field}: {str(path)!r} must end in .png, .pdf or .svg", field=field)
    return Path(path)


def plot_game(res: GameResults, path: str | Path, *, game: int = 0, frames=None, title: str | None = None) -> Path:
    """Save a row of panels of one recorded game to `path` (PNG); returns the path.

    frames: step indices to draw (default: default_frames); title: above the panels.
    Raises ValueError for results simulated without record=True.
    """
    if res.pursuer_paths is None:
        raise ValueError("plot_game needs results simulated with record=True")
    frames = default_frames(res, game) if frames is None else sorted(set(frames))
    fig, axes = new_figure(1, len(frames), figsize=(4.2 * len(frames), 4.4))
    for ax, frame in zip(axes[0], frames):
        draw_game(ax, res, game, frame)
    axes[0][-1].legend(loc="upper right", fontsize=8)  # the last panel shows every kind of marker
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
