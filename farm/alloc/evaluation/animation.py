"""`farm eval RUN --animate`: an episode of the allocation as a moving picture.

Each frame is the grid at one step of the episode (defenders blue, intruders red, as
env.render() and the density maps draw them), the cells engaged at that step outlined with
their games' team sizes n_p:n_e written in. Under `--fidelity games` a second panel shows one
engaged cell's real game: the first step that engages any cell, its cell with the most
evaders, played as `--fidelity games` plays a case's first fresh game (game number
`settings.games` of the case, farm.alloc.evaluation.fidelity); the episode holds at that step while the
game plays out frame by frame (farm.core.game_animation.game_frames' steps), and the game's end
stays shown after. An episode of T steps has T + 1 frames, plus the inset game's frames but
one (episode_frame_count).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farm.alloc.evaluation.rollout import Episode
from farm.alloc.game.plots import _rgb
from farm.core.game_animation import auto_stride, figure_frames, game_frame_steps, write_animation
from workers import GameResults, run_games

__all__ = ["InsetGame", "inset_game", "episode_frame_steps", "episode_frame_count", "episode_frames",
           "write_episode_animation"]

INSET_FRAMES = 40  # the inset game is shown in at most this many frames


@dataclass(frozen=True)
class InsetGame:
    """One engaged cell's game shown beside the grid: at episode step `step` (1-based: the
    engagement of the step that led to frame `step`), cell `cell` (flat index), n_p v n_e,
    its recorded GameResults `res` (one game) and the game steps to show `frames`."""

    step: int
    cell: int
    n_p: int
    n_e: int
    res: GameResults
    frames: list[int]


def inset_game(episode: Episode, settings) -> InsetGame | None:
    """The game of the episode's first engagement (its cell with the most evaders), played
    as `--fidelity games` plays a case's first fresh game; None for an episode that engaged
    nothing. episode: recorded (play(..., record_first=True)); settings: the run's
    GameSettings (its games and seed, and the game settings of every cell)."""
    for t, (cells, n_p, n_e) in enumerate(episode.engagements, start=1):
        if len(cells):
            k = int(np.argmax(n_e))
            key = settings.key(int(n_p[k]), int(n_e[k]))
            res = run_games(key.case, key.seed, settings.games, settings.games + 1, record=True)
            steps = int(res.steps[0])
            return InsetGame(t, int(cells[k]), int(n_p[k]), int(n_e[k]), res,
                             game_frame_steps(steps, auto_stride(steps, INSET_FRAMES)))
    return None


def episode_frame_steps(episode: Episode, inset: InsetGame | None = None) -> list[tuple[int, int | None]]:
    """What each frame shows: (episode step, inset game step or None), the episode's steps
    0..T, the inset's game steps all at the inset's episode step."""
    shown: list[tuple[int, int | None]] = []
    for t in range(len(episode.frames)):
        if inset is not None and t == inset.step:
            shown.extend((t, g) for g in inset.frames)
        else:
            shown.append((t, None if inset is None or t < inset.step else inset.frames[-1]))
    return shown


def episode_frame_count(episode: Episode, inset: InsetGame | None = None) -> int:
    """The frames of the episode's animation: T + 1, plus the inset game's frames but one."""
    return len(episode.frames) + (len(inset.frames) - 1 if inset is not None else 0)


def episode_frames(episode: Episode, title: str = "", inset: InsetGame | None = None,
                   dpi: int = 80) -> Iterator[np.ndarray]:
    """The frames of a recorded episode (episode_frame_steps) as (H, W, 3) uint8 arrays: the
    grid, the engaged cells outlined with n_p:n_e, and the inset game beside it when given."""
    from matplotlib.patches import Rectangle

    from farm.core.plots import draw_game, new_figure

    n = episode.frames[0][0].shape[0]
    T = len(episode.frames) - 1
    fig, axes = new_figure(1, 2 if inset is not None else 1, figsize=(9.6 if inset is not None else 5.0, 5.2))
    fig.set_dpi(dpi)
    grid_ax = axes[0][0]

    def draw(item: tuple[int, int | None]) -> None:
        t, g = item
        D, I = episode.frames[t]
        grid_ax.clear()
        grid_ax.imshow(_rgb(D, I), origin="upper", extent=(-0.5, n - 0.5, n - 0.5, -0.5))
        if t >= 1:
            cells, n_p, n_e = episode.engagements[t - 1]
            for cell, p, e in zip(cells.tolist(), n_p.tolist(), n_e.tolist()):
                r, c = divmod(cell, n)
                featured = inset is not None and t == inset.step and cell == inset.cell
                grid_ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, lw=3 if featured else 1.6,
                                            edgecolor="black" if featured else "gold"))
                grid_ax.text(c, r, f"{p}:{e}", ha="center", va="center", fontsize=max(5, 11 - n // 2))
        grid_ax.set_xticks([])
        grid_ax.set_yticks([])
        grid_ax.set_title(f"step {t} of {T}: defenders blue, intruders red; engaged n_p:n_e", fontsize=8)
        if inset is not None:
            game_ax = axes[0][1]
            game_ax.clear()
            if g is None:
                game_ax.set_axis_off()
                game_ax.set_title(f"the game of step {inset.step}: {inset.n_p} v {inset.n_e}, not yet", fontsize=8)
            else:
                game_ax.set_axis_on()
                draw_game(game_ax, inset.res, 0, g)
                r, c = divmod(inset.cell, n)
                game_ax.set_title(f"step {inset.step}, cell ({r}, {c}): {inset.n_p} v {inset.n_e}, "
                                  f"t = {g * inset.res.dt:.2f} s", fontsize=8)
        if title:
            fig.suptitle(title, fontsize=9)

    return figure_frames(fig, draw, episode_frame_steps(episode, inset))


def write_episode_animation(episode: Episode, path: str | Path, title: str = "", settings=None,
                            fps: float = 2.0) -> tuple[Path, int]:
    """Write a recorded episode's animation to path (.gif or .mp4); settings (the run's
    GameSettings) adds the inset game of its first engagement (`--fidelity games`).
    Returns (path, frames written). fps: the episode's steps a second; the inset game's
    frames play five times faster."""
    inset = inset_game(episode, settings) if settings is not None else None
    shown = episode_frame_steps(episode, inset)
    seconds = [1.0 / fps if inset is None or t != inset.step else 0.2 / fps for t, _ in shown]
    return write_animation(episode_frames(episode, title, inset), path, seconds=seconds)
