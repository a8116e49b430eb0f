"""Moving pictures: a recorded game frame by frame (`farm game --animate`), and the one way
every animation of the project is encoded (`write_animation`, also used by `farm eval --animate`).

Frames are drawn on a matplotlib `Figure` with an Agg canvas of its own (no pyplot, no backend
chosen, no global state) and read back as RGB arrays, then encoded by imageio: a `.gif` by its
Pillow plugin, an `.mp4` (H.264 in yuv420p, which browsers and players open) by
imageio-ffmpeg's bundled ffmpeg. Both come with the project's `video` extra (in `dev`).

A game's animation shows the steps 0, K, 2K, ... of the recorded game and always its last
step (the step it ended at: its last capture or escape, else t_max), so a game of `steps`
steps at frame stride K has `game_frame_count(steps, K)` = ceil(steps / K) + 1 frames.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from farm.core.checks import whole
from farm.core.errors import ConfigError
from workers import GameResults

__all__ = ["ANIMATION_SUFFIXES", "MAX_AUTO_FRAMES", "MAX_ANIMATION_BYTES", "GAME_FIGSIZE", "GAME_DPI", "FPS_RANGE",
           "check_animation_path", "check_pace", "animation_pace", "check_frames", "auto_stride", "game_frame_steps",
           "game_frame_count", "figure_frames", "game_frames", "write_animation", "read_frame_count"]

ANIMATION_SUFFIXES = (".gif", ".mp4")
MAX_AUTO_FRAMES = 120  # a game animated at the default stride has at most this many frames
MAX_ANIMATION_BYTES = 2**30  # the frames of one animation, held at once to be encoded: 1 GiB
GAME_FIGSIZE = (5.0, 5.2)  # a game's frame, in inches (game_frames)
GAME_DPI = 80  # ... and its dots an inch
FPS_RANGE = (0.1, 50.0)  # the frames a second an animation may be asked for
AUTO_FPS_RANGE = (1.0, 25.0)  # a game's own pace, kept within these frames a second


def check_animation_path(path, field: str = "animate") -> Path:
    """path as a Path when it names a .gif or .mp4 file, else a ConfigError naming field."""
    p = Path(path)
    if p.suffix.lower() not in ANIMATION_SUFFIXES:
        raise ConfigError(f"{field}: {str(path)!r} must end in .gif or .mp4", field=field)
    if p.is_dir():
        raise ConfigError(f"{field}: {p} is a folder, not a file to write", field=field)
    return p


def check_frames(count: int, width: int, height: int, field: str = "frame_stride", fix: str = "") -> None:
    """ConfigError (one line naming field) when `count` frames of width x height RGB pixels
    take more than MAX_ANIMATION_BYTES, which write_animation holds at once to encode them;
    fix: what to do instead, said after the cost."""
    needed = count * width * height * 3
    if needed > MAX_ANIMATION_BYTES:
        then = f"; {fix}" if fix else ""
        raise ConfigError(f"{field}: {count:,} frames of {width} x {height} pixels need {needed / 2**30:,.1f} GiB "
                          f"in memory to encode, more than {MAX_ANIMATION_BYTES // 2**30} GiB{then}", field=field)


def game_frame_size(dpi: int = GAME_DPI) -> tuple[int, int]:
    """(width, height) in pixels of a game's frame at dpi (GAME_FIGSIZE)."""
    return round(GAME_FIGSIZE[0] * dpi), round(GAME_FIGSIZE[1] * dpi)


def check_game_frames(steps: int, stride: int, field: str = "frame_stride", dpi: int = GAME_DPI) -> None:
    """check_frames of a `steps`-step game's animation at `stride` (game_frame_count frames of
    game_frame_size), naming field and the least stride that fits."""
    width, height = game_frame_size(dpi)
    fits = max(1, MAX_ANIMATION_BYTES // (width * height * 3))
    check_frames(game_frame_count(steps, stride), width, height, field,
                 f"a frame stride of at least {auto_stride(steps, fits)} fits")


def check_pace(stride: int | None, fps: float | None) -> None:
    """ConfigError naming frame_stride unless stride is None or >= 1, or fps unless it is None
    or within FPS_RANGE."""
    if stride is not None and stride < 1:
        raise ConfigError(f"frame_stride: must be a whole number >= 1, got {stride}", field="frame_stride")
    if fps is not None and not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
        raise ConfigError(f"fps: must be between {FPS_RANGE[0]:g} and {FPS_RANGE[1]:g} frames a second, got {fps:g}",
                          field="fps")


def animation_pace(steps: int, dt: float, stride: int | None = None, fps: float | None = None) -> tuple[int, float]:
    """(stride, fps) of a `steps`-step game's animation: stride, else auto_stride(steps); fps, else
    the game's own pace (a frame every stride steps of dt seconds) within AUTO_FPS_RANGE."""
    stride = stride or auto_stride(steps)
    if fps is None:
        fps = min(AUTO_FPS_RANGE[1], max(AUTO_FPS_RANGE[0], 1.0 / (stride * dt)))
    return stride, fps


def auto_stride(steps: int, max_frames: int = MAX_AUTO_FRAMES) -> int:
    """The smallest frame stride K >= 1 that shows a game of `steps` steps in at most max_frames frames."""
    return max(1, math.ceil(steps / max(1, max_frames - 1)))


def game_frame_steps(steps: int, stride: int) -> list[int]:
    """The step indices an animation of a `steps`-step game at `stride` shows: 0, K, 2K, ... and steps."""
    whole("frame_stride", stride, 1)
    shown = list(range(0, steps + 1, stride))
    if shown[-1] != steps:
        shown.append(steps)
    return shown


def game_frame_count(steps: int, stride: int) -> int:
    """How many frames game_frame_steps(steps, stride) shows: ceil(steps / stride) + 1."""
    return math.ceil(steps / stride) + 1


def figure_frames(fig, draw, items: Iterable) -> Iterator[np.ndarray]:
    """For each item, draw(item) onto fig (which draw clears and redraws) and yield the canvas
    as an (H, W, 3) uint8 RGB array; every frame has the figure's size in pixels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    for item in items:
        draw(item)
        canvas.draw()
        yield np.asarray(canvas.buffer_rgba())[..., :3].copy()


def game_frames(res: GameResults, game: int = 0, stride: int | None = None, title: str | None = None,
                dpi: int = GAME_DPI) -> Iterator[np.ndarray]:
    """The frames of one recorded game: its agents, trajectories so far and Voronoi cells
    (farm.core.plots.draw_game) at each of game_frame_steps(res.steps[game], stride) (stride
    None: auto_stride), as (H, W, 3) uint8 arrays. res: simulated with record=True.
    ConfigError naming frame_stride, before any frame, when they are too many to encode
    (check_game_frames)."""
    from farm.core.plots import draw_game, new_figure

    if res.pursuer_paths is None:
        raise ValueError("game_frames needs results simulated with record=True")
    steps = int(res.steps[game])
    stride = auto_stride(steps) if stride is None else stride
    check_game_frames(steps, stride, dpi=dpi)
    fig, axes = new_figure(1, 1, figsize=GAME_FIGSIZE)
    fig.set_dpi(dpi)
    ax = axes[0][0]

    def draw(frame: int) -> None:
        ax.clear()
        draw_game(ax, res, game, frame)
        ax.legend(loc="upper right", fontsize=7)
        if title:
            fig.suptitle(title, fontsize=9)

    return figure_frames(fig, draw, game_frame_steps(steps, stride))


def write_animation(frames: Iterable[np.ndarray], path: str | Path, fps: float = 10.0,
                    seconds: list[float] | None = None) -> tuple[Path, int]:
    """Encode frames ((H, W, 3) uint8 each, all one size) into path, a .gif or .mp4 (its
    suffix chooses), written atomically (a partial file never has path's name); returns
    (path, the number of frames written). fps: frames a second, or seconds: how long each
    frame shows (a .gif keeps each frame's own duration; an .mp4, at a constant rate, repeats
    a frame for as many periods of the shortest duration as it lasts). ConfigError for
    another suffix, an empty animation, or frames of more than MAX_ANIMATION_BYTES."""
    path = check_animation_path(path)
    try:
        import imageio.v3 as iio
    except ImportError:
        raise ConfigError("animate: writing animations needs imageio: pip install 'swarm-farm[video]'",
                          field="animate") from None
    frames = _held(frames)
    if not frames:
        raise ConfigError("animate: no frames to write", field="animate")
    seconds = [1.0 / fps] * len(frames) if seconds is None else list(seconds)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.partial{path.suffix}")
    stack = np.stack(frames)
    if path.suffix.lower() == ".gif":
        iio.imwrite(partial, stack, extension=".gif", duration=[1000.0 * s for s in seconds], loop=0)
    else:
        period = min(seconds)
        repeats = [max(1, round(s / period)) for s in seconds]
        even = stack[:, : stack.shape[1] // 2 * 2, : stack.shape[2] // 2 * 2]  # H.264 in yuv420p wants even sizes
        iio.imwrite(partial, np.repeat(even, repeats, axis=0), plugin="FFMPEG", fps=1.0 / period, macro_block_size=2)
    partial.replace(path)
    return path, len(frames)


def _held(frames: Iterable[np.ndarray]) -> list[np.ndarray]:
    """The frames as a list, ConfigError naming animate as soon as they take more than
    MAX_ANIMATION_BYTES (before the next frame is drawn)."""
    held, size = [], 0
    for frame in frames:
        size += np.asarray(frame).nbytes
        if size > MAX_ANIMATION_BYTES:
            raise ConfigError(f"animate: more than {MAX_ANIMATION_BYTES // 2**30} GiB of frames to encode "
                              f"({len(held) + 1:,} frames so far); show fewer", field="animate")
        held.append(frame)
    return held


def read_frame_count(path: str | Path) -> int:
    """How many frames the animation (or video) at path holds, read back by decoding it."""
    import imageio.v3 as iio

    path = Path(path)
    plugin = "FFMPEG" if path.suffix.lower() == ".mp4" else None
    return sum(1 for _ in iio.imiter(path, plugin=plugin))
