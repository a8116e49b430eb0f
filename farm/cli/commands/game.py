"""`farm game`: play one pursuit-evasion game, print each evader's fate, optionally plot or
animate it."""

from __future__ import annotations

import numpy as np

from workers import sample_initial_positions, simulate_case

from farm.cli.options import (
    add_game_options,
    checked_case,
    flags,
    floats,
    game_settings,
    load_json,
    points,
    refuse_contradictions,
)
from farm.core.errors import CliError
from farm.games.start import positions_document, start_arrays

# Flags that contradict each other: a given start leaves nothing to sample.
CONTRADICTIONS = [("positions", "pursuers"), ("positions", "evaders"), ("positions", "n_pursuers"),
                  ("positions", "n_evaders"), ("positions", "seed"), ("positions", "law"),
                  ("pursuers", "n_pursuers"), ("evaders", "n_evaders"), ("pursuers", "seed"),
                  ("evaders", "seed"), ("pursuers", "law"), ("evaders", "law")]


def register(subparsers) -> None:
    """Add `farm game` and its flags to the `farm` parser's subcommands."""
    g = subparsers.add_parser("game", help="play one pursuit-evasion game; print each evader's capture or escape time")
    src = g.add_argument_group("initial positions (default: sampled)")
    src.add_argument("--positions", help="JSON file {\"pursuers\": [[x, y], ...], \"evaders\": [[x, y], ...]}")
    src.add_argument("--pursuers", help="pursuer positions 'x,y;x,y;...'")
    src.add_argument("--evaders", help="evader positions 'x,y;x,y;...'")
    src.add_argument("--n-pursuers", type=int, help="sampled start: pursuers (default 3)")
    src.add_argument("--n-evaders", type=int, help="sampled start: evaders (default 1)")
    src.add_argument("--seed", type=int, help="sampled start: the game's seed (default 0)")
    add_game_options(g)
    g.add_argument("--plot", help="write a figure of the trajectories and Voronoi cells here (.png, .pdf or .svg)")
    g.add_argument("--plot-times", help="times in s of the panels, e.g. '0,1,2' (default: start, middle, end)")
    g.add_argument("--animate", metavar="PATH", help="write an animation of the game here (.gif or .mp4)")
    g.add_argument("--frame-stride", type=int, metavar="K",
                   help="animate every K-th step (default: at most 120 frames)")
    g.add_argument("--fps", type=float, help="frames per second of --animate (default: real time, from 1 to 25)")
    g.set_defaults(func=run)


def run(args) -> int:
    """Play the game of the flags and print its teams and each evader's fate; write its figure
    (--plot) and animation (--animate). Every flag is checked before the game is played."""
    settings = _checked_settings(args)
    p, e = _start(args, settings)
    if args.positions or args.pursuers:  # the start is given: no initial-position law applies
        settings = {**settings, "law": {"kind": "uniform"}}
    case = checked_case({"n_pursuers": p.shape[1], "n_evaders": e.shape[1], **settings})
    res = simulate_case(case, p, e, record=args.plot is not None or args.animate is not None)
    if args.animate is not None and args.frame_stride is not None:  # its frames fit, before anything is shown
        from farm.core.game_animation import check_game_frames

        with flags("frame_stride"):
            check_game_frames(int(res.steps[0]), args.frame_stride)
    _print_game(case, res, e)
    if args.plot is not None:
        _plot_game(args, res)
    if args.animate is not None:
        _animate_game(args, case, res)
    return 0


def _checked_settings(args) -> dict:
    """The game settings of the flags (game_settings), once the flags are checked: CliError for
    a figure or animation path that cannot be written, flags that contradict each other, and
    flags that need one not given; all before the game is played."""
    from farm.core.output import check_writable_file

    # a flag is given when it is not None: an empty path is refused as a path, never read as "not given"
    if args.plot is not None:
        from farm.core.plots import check_figure_path

        with flags("plot"):
            check_writable_file(check_figure_path(args.plot), "plot")  # before the game: a read-only place
    settings = game_settings(args)
    refuse_contradictions(args, CONTRADICTIONS)
    if args.plot_times is not None and args.plot is None:
        raise CliError("--plot-times: is for the figure of --plot, which is not given")
    if args.frame_stride is not None and args.animate is None:
        raise CliError("--frame-stride: is for the animation of --animate, which is not given")
    if args.animate is not None:
        from farm.core.game_animation import check_animation_path, check_pace

        with flags("animate", "frame_stride", "fps"):
            check_writable_file(check_animation_path(args.animate), "animate")
            check_pace(args.frame_stride, args.fps)
    elif args.fps is not None:
        raise CliError("--fps: is for the animation of --animate, which is not given")
    return settings


def _start(args, settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """The game's start, pursuers (1, n_p, 2) and evaders (1, n_e, 2) float64: from the
    --positions JSON file, from --pursuers and --evaders, or drawn by the case's initial-position
    law with --seed (team sizes --n-pursuers and --n-evaders, default 3 and 1)."""
    if args.positions:
        with flags("positions"):
            pursuers, evaders = positions_document(load_json(args.positions, "--positions"))
    elif args.pursuers or args.evaders:
        if not (args.pursuers and args.evaders):
            raise CliError("--pursuers and --evaders go together")
        pursuers, evaders = points(args.pursuers, "--pursuers"), points(args.evaders, "--evaders")
    else:
        n_p = 3 if args.n_pursuers is None else args.n_pursuers
        n_e = 1 if args.n_evaders is None else args.n_evaders
        case = checked_case({"n_pursuers": n_p, "n_evaders": n_e, **settings})
        p, e = sample_initial_positions(case, 0 if args.seed is None else args.seed, 0, 1)
        pursuers, evaders = p[0], e[0]
    return start_arrays(pursuers, evaders)


def _print_game(case, res, e: np.ndarray) -> None:
    """The game's teams and settings in one line, then each evader's start and its fate: its
    capture time, its escape, or neither by t_max. e: the evaders' start, (1, n_e, 2)."""
    exit_point = case.exit_point
    extras = [f"{name.replace('_', ' ')} {getattr(case, name):g}" for name in ("pursuer_speed", "evader_speed")
              if getattr(case, name) != 1.0]
    if exit_point is not None:
        extras.append(f"exit at ({exit_point[0]:g}, {exit_point[1]:g})")
    print(f"{case.n_pursuers} pursuer(s) {case.pursuer_policy} vs {case.n_evaders} evader(s) {case.evader_policy}"
          + (f" ({', '.join(extras)})" if extras else ""))
    for i, (t, t_escape) in enumerate(zip(res.capture_times[0], res.escape_times[0])):
        if np.isfinite(t):
            shown = f"{t:.2f} s"
        elif np.isfinite(t_escape):
            shown = f"escaped at {t_escape:.2f} s"
        else:
            shown = f"not captured by t_max = {case.t_max:g} s" + (", not escaped" if exit_point is not None else "")
        print(f"  evader {i} at ({e[0, i, 0]:.2f}, {e[0, i, 1]:.2f}): {shown}")


def _plot_game(args, res) -> None:
    """The figure of --plot: the game at the --plot-times given (seconds), else at default_frames."""
    from farm.core.plots import default_frames, frames_at, plot_game

    frames = None
    if args.plot_times:
        with flags("plot_times"):
            frames = frames_at(res, floats(args.plot_times, "--plot-times"), field="plot_times")
    path = plot_game(res, args.plot, frames=frames or default_frames(res, 0))
    print(f"figure: {path}")


def _animate_game(args, case, res) -> None:
    """The animation of --animate, at the pace of --frame-stride and --fps (animation_pace)."""
    from farm.core.game_animation import animation_pace, game_frames, write_animation

    stride, fps = animation_pace(int(res.steps[0]), res.dt, args.frame_stride, args.fps)
    title = f"{case.n_pursuers} {case.pursuer_policy} vs {case.n_evaders} {case.evader_policy}"
    with flags("animate"):
        path, count = write_animation(game_frames(res, 0, stride, title=title), args.animate, fps=fps)
    print(f"animation: {path} ({count} frames, every {stride} step(s) of {int(res.steps[0])})")
