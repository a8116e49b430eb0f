"""The `farm` command line. Bad input ends in one line `farm: error: ...`, exit 2."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from farm.core.checks import is_finite_number, whole
from farm.core.config import case_from
from farm.core.errors import CliError
from workers import GAME_FIELDS, SwarmFarmError, sample_initial_positions, simulate_case
from workers.policies import EVADER_POLICIES, PURSUER_POLICIES

# Flags of the game's settings: one per workers.Case field, default None (Case's default).
GAME_FLAG_HELP = {
    "pursuer_policy": f"one of {', '.join(sorted(PURSUER_POLICIES))}",
    "evader_policy": f"one of {', '.join(sorted(EVADER_POLICIES))}",
    "target": "target point of `target` evaders, 'x,y'",
    "arena": "JSON file with the arena's vertices [[x, y], ...] (default: [0,10]^2 square)",
    "exit_point": "'x,y': an evader within r_c of it escapes (model v2; default: no exit)",
    "law": "initial positions: boxes (the paper's start boxes) or uniform",
    "pursuer_speed": "pursuers' top speed",
    "evader_speed": "evaders' top speed",
}
GAME_FLAGS = tuple(name for name in GAME_FIELDS if name not in ("n_pursuers", "n_evaders", "tau"))
SPEED_FLAGS = ("pursuer_speed", "evader_speed")
DEBUG_ENV = "SWARM_FARM_DEBUG"


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise CliError(message if self.prog == "farm" else f"{self.prog.split()[-1]}: {message}")


@contextmanager
def flags(*names: str, **renamed: str):
    """Re-raise a library error about a field the command has a flag for as that flag's error:
    an error with field "out" becomes "--out: <its problem>". names: fields named as their
    flags; renamed: flag=field where the library's field is named otherwise. A dotted field
    (law.kind) maps through its first part (--law: kind: ...)."""
    to_flag = {**{n: n for n in names}, **{field: flag for flag, field in renamed.items()}}
    try:
        yield
    except SwarmFarmError as e:
        field = getattr(e, "field", None)
        name, _, sub = (field or "").partition(".")
        if name in to_flag:
            raise CliError(f"--{to_flag[name].replace('_', '-')}: {sub + ': ' if sub else ''}{e.problem}") from None
        raise


def _contradictions(args, pairs) -> None:
    """CliError naming both flags when two flags that contradict each other (or one that the
    other makes ignored) are both given; a flag counts as given when it is not None."""
    for first, second in pairs:
        if getattr(args, first) is not None and getattr(args, second) is not None:
            raise CliError(f"--{first.replace('_', '-')} and --{second.replace('_', '-')}: give one or the other "
                           f"(with --{first.replace('_', '-')}, --{second.replace('_', '-')} would be ignored)")


def _floats(text: str, field: str, n: int | None = None) -> list[float]:
    entries = text.replace(";", ",").split(",")
    if text.strip() and any(not x.strip() for x in entries):
        raise CliError(f"{field}: an empty entry in {text!r}")
    try:
        values = [float(x) for x in entries if x.strip()]
    except ValueError:
        raise CliError(f"{field}: expected comma-separated numbers, got {text!r}") from None
    if n is not None and len(values) != n:
        raise CliError(f"{field}: expected {n} numbers, got {text!r}")
    return values


def _xy_pairs(value, field: str) -> list:
    """value when it is a list of [x, y] pairs of finite numbers (not booleans), else CliError naming field."""
    if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 for p in value):
        raise CliError(f"{field}: expected a list of [x, y] pairs, got {json.dumps(value)[:60]}")
    for p in value:
        if not all(is_finite_number(v) for v in p):
            raise CliError(f"{field}: {json.dumps(p)[:60]} is not a pair of finite numbers")
    return value


def _points(text: str, field: str) -> np.ndarray:
    v = _floats(text, field)
    if len(v) == 0 or len(v) % 2:
        raise CliError(f"{field}: expected x,y pairs like '4,5;8,5', got {text!r}")
    return np.array(v).reshape(-1, 2)


def _load_json(path: str, field: str):
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CliError(f"{field}: no such file {path!r}") from None
    except OSError as e:
        raise CliError(f"{field}: cannot read {path!r} ({e.strerror or type(e).__name__})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CliError(f"{field}: {path!r} is not valid JSON ({e.__class__.__name__})") from None


def _add_game_options(p: argparse.ArgumentParser, names=GAME_FLAGS) -> None:
    from workers import Case

    defaults = {f: v.default for f, v in Case.__dataclass_fields__.items()}
    for name in names:
        default = defaults.get(name)
        shown = "the paper's boxes" if name == "law" else "none" if default is None else default
        p.add_argument("--" + name.replace("_", "-"), dest=name, default=None, metavar=name.upper(),
                       help=f"{GAME_FLAG_HELP.get(name, name.replace('_', ' '))} (default: {shown})")


def _game_settings(args, names=GAME_FLAGS) -> dict:
    """The game flags given, as plain values for farm.core.config.case_from."""
    out = {}
    for name in names:
        text = getattr(args, name)
        if text is None:
            continue
        flag = "--" + name.replace("_", "-")
        if name in ("target", "exit_point"):
            out[name] = _floats(text, flag, 2)
        elif name == "arena":
            out[name] = _load_json(text, flag)
        elif name == "law":
            out[name] = {"kind": text}
        else:
            out[name] = text
    return out


def _case(fields: dict):
    """case_from(fields), its error naming the flag when the field came from one."""
    with flags(*GAME_FLAGS, "n_pursuers", "n_evaders"):
        return case_from(fields)


def cmd_game(args) -> int:
    """`farm game`: play one pursuit-evasion game, print its capture times, optionally plot it."""
    settings = _checked_settings(args)
    p, e = _game_start(args, settings)
    if args.positions or args.pursuers:  # the start is given: no initial-position law applies
        settings = {**settings, "law": {"kind": "uniform"}}
    case = _case({"n_pursuers": p.shape[1], "n_evaders": e.shape[1], **settings})
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
    """The game settings of `farm game`'s flags (_game_settings), once the flags are checked:
    CliError for a figure or animation path that cannot be written, flags that contradict each
    other, and flags that need one not given; all before the game is played."""
    from farm.core.output import check_writable_file

    # a flag is given when it is not None: an empty path is refused as a path, never read as "not given"
    if args.plot is not None and Path(args.plot).suffix.lower() not in (".png", ".pdf", ".svg"):
        raise CliError(f"--plot: {args.plot!r} must end in .png, .pdf or .svg")
    if args.plot is not None:
        with flags("plot"):
            check_writable_file(args.plot, "plot")  # before the game: a read-only place is found now
    settings = _game_settings(args)
    _contradictions(args, [("positions", "pursuers"), ("positions", "evaders"), ("positions", "n_pursuers"),
                        ("positions", "n_evaders"), ("positions", "seed"), ("positions", "law"),
                        ("pursuers", "n_pursuers"), ("evaders", "n_evaders"), ("pursuers", "seed"),
                        ("evaders", "seed"), ("pursuers", "law"), ("evaders", "law")])
    if args.plot_times is not None and args.plot is None:
        raise CliError("--plot-times: is for the figure of --plot, which is not given")
    if args.frame_stride is not None and args.animate is None:
        raise CliError("--frame-stride: is for the animation of --animate, which is not given")
    if args.animate is not None:
        from farm.core.game_animation import check_animation_path

        with flags("animate"):
            check_writable_file(check_animation_path(args.animate), "animate")
        if args.frame_stride is not None and args.frame_stride < 1:
            raise CliError(f"--frame-stride: must be a whole number >= 1, got {args.frame_stride}")
        if args.fps is not None and not 0.1 <= args.fps <= 50:
            raise CliError(f"--fps: must be between 0.1 and 50 frames a second, got {args.fps:g}")
    elif args.fps is not None:
        raise CliError("--fps: is for the animation of --animate, which is not given")
    return settings


def _game_start(args, settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """The game's start, pursuers (1, n_p, 2) and evaders (1, n_e, 2) float64: from the
    --positions JSON file, from --pursuers and --evaders, or drawn by the case's initial-position
    law with --seed (team sizes --n-pursuers and --n-evaders, default 3 and 1)."""
    if args.positions:
        data = _load_json(args.positions, "--positions")
        if not isinstance(data, dict) or not {"pursuers", "evaders"} <= set(data):
            raise CliError("--positions: JSON must be an object with 'pursuers' and 'evaders' lists of [x, y]")
        unknown = sorted(set(data) - {"pursuers", "evaders"})
        if unknown:
            raise CliError(f"--positions: unknown key {unknown[0]!r} (the JSON holds 'pursuers' and 'evaders' only)")
        pursuers, evaders = (_xy_pairs(data[side], f"--positions: {side}") for side in ("pursuers", "evaders"))
    elif args.pursuers or args.evaders:
        if not (args.pursuers and args.evaders):
            raise CliError("--pursuers and --evaders go together")
        pursuers, evaders = _points(args.pursuers, "--pursuers"), _points(args.evaders, "--evaders")
    else:
        n_p = 3 if args.n_pursuers is None else args.n_pursuers
        n_e = 1 if args.n_evaders is None else args.n_evaders
        case = _case({"n_pursuers": n_p, "n_evaders": n_e, **settings})
        p, e = sample_initial_positions(case, 0 if args.seed is None else args.seed, 0, 1)
        pursuers, evaders = p[0], e[0]
    try:
        p = np.array(pursuers, dtype=np.float64)[None]
        e = np.array(evaders, dtype=np.float64)[None]
    except (TypeError, ValueError):
        raise CliError("positions: expected lists of [x, y] pairs") from None
    if p.ndim != 3 or e.ndim != 3 or p.shape[1] == 0 or e.shape[1] == 0:
        raise CliError("positions: expected non-empty lists of [x, y] pairs")
    return p, e


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
    from farm.core.plots import default_frames, plot_game

    frames = None
    if args.plot_times:
        times = _floats(args.plot_times, "--plot-times")
        if not all(np.isfinite(t) and t >= 0 for t in times):
            raise CliError("--plot-times: times must be finite and >= 0")
        frames = [int(round(t / res.dt)) for t in times]
        frames = [min(f, int(res.steps[0])) for f in frames]
    frames = frames or default_frames(res, 0)
    path = plot_game(res, args.plot, frames=frames)
    print(f"figure: {path}")


def _animate_game(args, case, res) -> None:
    """The animation of --animate: every --frame-stride-th step (default auto_stride), at --fps
    frames a second (default: the game's pace, from 1 to 25)."""
    from farm.core.game_animation import auto_stride, game_frames, write_animation

    stride = args.frame_stride or auto_stride(int(res.steps[0]))
    title = f"{case.n_pursuers} {case.pursuer_policy} vs {case.n_evaders} {case.evader_policy}"
    fps = min(25.0, max(1.0, 1.0 / (stride * res.dt))) if args.fps is None else args.fps
    with flags("animate"):
        path, count = write_animation(game_frames(res, 0, stride, title=title), args.animate, fps=fps)
    print(f"animation: {path} ({count} frames, every {stride} step(s) of {int(res.steps[0])})")


def cmd_pe_table(args) -> int:
    """`farm pe-table`: the paper's Tables 1 and 2 (Monte Carlo), with figures."""
    from farm.games.pe_table import format_tables, pe_size, speeds_text, write_pe_tables
    from farm.games.sizes import check_size

    if args.games < 2:
        raise CliError(f"--games: need at least 2 games per case for a CI, got {args.games}")
    base = _case({"n_pursuers": 1, "n_evaders": 1, **_game_settings(args, SPEED_FLAGS)})
    check_size(pe_size(args.games, base), yes=args.yes, cpus=1)
    paper_speeds = base.pursuer_speed == base.evader_speed == 1.0
    out = args.out or ("results/pe-table" if paper_speeds
                    else f"results/pe-table-speeds-{base.pursuer_speed:g}-{base.evader_speed:g}")
    if Path(out).exists() and not Path(out).is_dir():
        raise CliError(f"--out: {out} exists and is not a folder")
    from farm.core.output import check_writable_folder

    with flags("out"):
        check_writable_folder(out, "out")  # before the games: a read-only --out is found now, not at the end
    t0 = time.perf_counter()
    written, summary = write_pe_tables(
        Path(out), args.games, args.seed, args.format, progress=lambda m: print("  " + m, file=sys.stderr),
        figures=not args.no_figures, base=base,
    )
    print(format_tables(summary))
    print("Our numbers come from the model of docs/model.md; the paper's evader target point and runs are unknown.")
    if not paper_speeds:
        print(f"These games ran at {speeds_text(base)}; the paper's figures are for equal speeds "
              "(1 and 1): a sensitivity check, not a fit.")
    for path in written:
        print(f"wrote {path}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_sweep(args) -> int:
    """`farm sweep CONFIG`: run or resume a parametric Monte Carlo sweep; prints its summary."""
    from farm.games.sweep import format_summary, load_sweep_config, print_info, run_sweep

    no_ray = True if args.no_ray else None
    _contradictions(argparse.Namespace(no_ray=no_ray, address=args.address, workers=args.workers,
                                       metrics_port=args.metrics_port),
                    [("no_ray", "address"), ("no_ray", "workers"), ("no_ray", "metrics_port"),
                     ("address", "metrics_port")])
    if args.metrics_port is not None and not 1 <= args.metrics_port <= 65535:
        raise CliError(f"--metrics-port: must be a TCP port from 1 to 65535, got {args.metrics_port}")
    if args.metrics_port is not None and os.environ.get("RAY_ADDRESS"):
        raise CliError("--metrics-port: is for a local Ray, but RAY_ADDRESS names a cluster to join")
    config = load_sweep_config(args.config)
    out = Path(args.out) if args.out else Path("results") / "sweeps" / config.name
    with flags("out", "address", "metrics_port", "rebuild", "workers", workers="num_cpus"):
        summary, info = run_sweep(config, out, address=args.address, workers=args.workers, use_ray=not args.no_ray,
                                  show_progress=not args.quiet, metrics_port=args.metrics_port, yes=args.yes,
                                  rebuild=args.rebuild)
    print_info(info)
    print(f"{config.name}: {len(summary)} point(s), {int(summary['n_games'].sum())} games")
    print(format_summary(summary, config.vary.names()))
    print(f"results: {out}/summary.parquet, {out}/summary.csv, {out}/shards/")
    return 0


def cmd_table(args) -> int:
    """`farm table [show] CONFIG`: fill the capture-time store over a table's cells, or show it."""
    from farm.service.table import fill_table, load_table_config, plot_heatmaps, table_frames

    words = list(args.args)
    show = bool(words) and words[0] == "show"
    if show:
        words = words[1:]
    if len(words) != 1:
        raise CliError("table: usage: farm table CONFIG | farm table show CONFIG")
    if show:
        for flag in ("address", "workers", "yes"):
            if getattr(args, flag) not in (None, False):
                raise CliError(f"--{flag}: `farm table show` only reads the store; --{flag} is for `farm table`")
    _contradictions(args, [("address", "workers")])
    config = load_table_config(words[0])
    if not show:
        from farm.games.sizes import check_size
        from farm.runtime import check_workers

        with flags("store", "address", "workers", workers="num_cpus"):
            check_workers(args.workers)
            check_size(config.size(), yes=args.yes, cpus=args.workers or 2)
            info = fill_table(config, store=args.store, address=args.address, workers=args.workers,
                              show_progress=not args.quiet)
        print(f"{config.name}: {info['cases']} cases, {info['computed']} computed, the rest from the store "
              f"({info['seconds']:.1f} s)")
    out = Path(args.plot_dir or config.store_path(args.store).parent / "tables")
    for settings, mean, frac in table_frames(config, store=args.store):
        print(f"\n{settings.game.pursuer_policy} vs {settings.game.evader_policy}: mean capture time (s)")
        print(mean.to_string(float_format=lambda x: f"{x:.2f}", na_rep="-"))
        print(f"fraction of evaders captured within tau = {settings.game.tau:g} s")
        print(frac.to_string(float_format=lambda x: f"{x:.2f}", na_rep="-"))
        name = f"{config.name}_{settings.game.pursuer_policy}_vs_{settings.game.evader_policy}.png"
        print(f"heatmaps: {plot_heatmaps(settings, mean, frac, out / name)}")
    return 0


def cmd_report(args) -> int:
    """`farm report RESULTS_DIR`: one self-contained HTML page of a results folder."""
    from farm.report import write_report

    path = write_report(args.results_dir, args.output)
    print(f"report: {path.resolve()}")
    return 0


def cmd_train(args) -> int:
    """`farm train CONFIG`: train the TD3 allocator into a run folder; prints its metrics."""
    from farm.alloc.training import load_train_config, train

    config = load_train_config(args.config, trainable=False)  # checked below, with --timesteps applied
    if args.timesteps is not None:
        if args.timesteps < 1:
            raise CliError(f"--timesteps: must be >= 1, got {args.timesteps}")
        starts = getattr(config.learner, "learning_starts", None)
        if starts is not None and args.timesteps <= starts:
            raise CliError(f"--timesteps: {args.timesteps} steps, but {config.algo}.learning_starts is {starts}: "
                           f"the model would never be updated")
        config = config.with_timesteps(args.timesteps)
    from farm.alloc.training.config import check_trainable

    try:
        check_trainable(config)  # with --timesteps applied: its own check above named the flag
    except SwarmFarmError as e:
        raise CliError(f"{args.config}: {e}") from None
    if args.service:
        config = config.model_copy(update={"service": config.service.model_copy(update={"mode": args.service})})
    if args.threads is not None:
        if args.threads < 1:
            raise CliError(f"--threads: must be >= 1, got {args.threads}")
        config = config.model_copy(update={"threads": args.threads})
    out = Path(args.out or Path("results") / "runs" / config.name)
    with flags("out", "resume"):
        metrics = train(config, out, resume=args.resume, show_progress=not args.quiet)
    print(json.dumps(metrics, indent=2))
    print(f"run: {out}")
    return 0


def _references(text: str) -> list[str]:
    """--references' names: `none` alone for none; CliError for an empty entry, a name given
    twice, or `none` beside names (which it would contradict)."""
    names = [n.strip() for n in text.split(",")]
    if any(not n for n in names):
        raise CliError(f"--references: an empty entry in {text!r}")
    if "none" in names and len(names) > 1:
        other = next(n for n in names if n != "none")
        raise CliError(f"--references: 'none' and {other!r} contradict each other; give none alone, or the names")
    twice = next((n for k, n in enumerate(names) if n in names[:k]), None)
    if twice is not None:
        raise CliError(f"--references: {twice!r} is named twice")
    return [] if names == ["none"] else names


def cmd_eval(args) -> int:
    """`farm eval RUN_DIR`: the trained policy, the baselines and the planners on the same seeded episodes."""
    from farm.alloc.evaluation.evaluate import evaluate_run, fidelity_lines

    run_dir = Path(args.run_dir)
    references = None if args.references is None else _references(args.references)
    with flags("episodes", "seed", "fidelity", "scenario", "references", "repair"):
        result = evaluate_run(run_dir, episodes=args.episodes, seed=args.seed, fidelity=args.fidelity,
                              scenario=args.scenario, references=references, animate=args.animate,
                              show_progress=not args.quiet, repair=args.repair)
    run_dir = result.folder
    print(result.table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    if result.games_table is not None:
        print("\n--fidelity games (every engaged cell's game simulated each step):")
        print(result.games_table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
        for line in fidelity_lines(result):
            print(line)
    print(f"wrote {run_dir / 'eval_table.csv'}, eval_episodes.csv, eval_steps.csv, behaviour_steps.png and "
          "density maps density_<policy>.png")
    if result.animation is not None:
        print(f"animation: {result.animation[0]} ({result.animation[1]} frames)")
    return 0


CLAIM_RUNS = ("paper_3x3_c1_0", "paper_3x3_c1_1.5")  # `farm claims`' default --c0 and --c15 run folders


def cmd_claims(args) -> int:
    """`farm claims RUNS_DIR`: the paper's claims (args)-(c), measured on evaluated runs; on an
    experiment folder (its experiment.json), over its seeds."""
    from farm.core.output import write_table
    from farm.studies.claims import check_claim_runs, claims
    from farm.studies.experiments.folder import is_experiment

    runs = Path(args.runs_dir)
    if not runs.is_dir():
        raise CliError(f"{runs}: not a folder of training runs")
    if is_experiment(runs):
        for flag, value in (("--c0", args.c0), ("--c15", args.c15)):
            if value is not None:
                raise CliError(f"{flag}: names a run of a folder of runs; {runs} is an experiment folder "
                               f"(--points names its points)")
        return _claims_over_seeds(runs, args.points)
    if args.points is not None:
        raise CliError(f"--points: names points of an experiment folder; {runs} holds no experiment.json")
    c0, c15 = args.c0 or CLAIM_RUNS[0], args.c15 or CLAIM_RUNS[1]
    note = check_claim_runs(runs, c0, c15, named=(args.c0 is not None, args.c15 is not None))
    if note is not None:
        print(note)
    rows = claims(runs, c0, c15)
    if not rows:
        raise CliError(f"{runs}: no evaluated runs (run farm train, then farm eval, for each config)")
    for r in rows:
        print(f"{r['claim']}\n  measured: {r['measured']}\n  verdict:  {r['verdict']}")
    write_table(pd.DataFrame(rows), runs / "claims", "csv")
    print(f"wrote {runs / 'claims.csv'}")
    return 0


def _claims_over_seeds(folder: Path, points) -> int:
    """`farm claims EXPERIMENT_DIR`: the claims over the experiment's seeds; claims.csv and claims_seeds.csv."""
    from farm.studies.claims import claims_over_seeds, write_claims_over_seeds

    found = claims_over_seeds(folder, None if points is None else tuple(points))
    print(found.note)
    if not found.rows:
        raise CliError(f"{folder}: no finished trial with its evaluations yet (farm experiments writes them)")
    for r in found.rows:
        print(f"{r['claim']}\n  measured: {r['measured']}\n  verdict:  {r['verdict']}\n  rule:     {r['rule']}")
    print("wrote " + ", ".join(map(str, write_claims_over_seeds(folder, found))))
    return 0


def cmd_suite(args) -> int:
    """`farm suite CONFIG --out DIR`: every policy on every scenario, on the same seeded episodes; a leaderboard."""
    from farm.studies.suite import format_leaderboard, load_suite_config, run_suite

    for flag, least in (("episodes", 1), ("games", 2)):
        value = getattr(args, flag)
        if value is not None and value < least:
            raise CliError(f"--{flag}: must be >= {least}, got {value}")
    config = load_suite_config(args.config)
    if args.games is not None:
        config = config.model_copy(update={"env": {**config.env, "games": args.games}})
    out = Path(args.out)
    with flags("out", "address", "episodes", "workers", workers="num_cpus"):
        board, info = run_suite(config, out, episodes=args.episodes, address=args.address, workers=args.workers,
                                show_progress=not args.quiet)
    print(format_leaderboard(board))
    print(f"{config.name}: {info['tasks']} (scenario, policy) evaluations on {info['workers']} worker(s), "
          f"{info['warmed_cases']} lattice cases warmed in {info['warm_seconds']:.1f} s, evaluations "
          f"{info['evaluation_seconds']:.1f} s", file=sys.stderr)
    print(f"wrote {out / 'leaderboard.csv'}, episodes.csv, leaderboard.png, suite.json")
    return 0


def cmd_experiments(args) -> int:
    """`farm experiments CONFIG --out DIR`: TD3 trainings over a grid and seeds as Ray Tune trials
    on one capture-time service; trials.csv and summary.csv (resumable)."""
    from farm.studies.experiments import format_summary, load_experiment_config, run_experiment
    from farm.studies.experiments.storage import is_uri

    config = load_experiment_config(args.config)
    # a URI: the experiment in object storage (docs/experiments.md)
    out = args.out if is_uri(args.out) else Path(args.out)
    with flags("out", "address", "workers", workers="num_cpus"):
        trials, summary, info = run_experiment(config, out, source=str(args.config), address=args.address,
                                               workers=args.workers, show_progress=not args.quiet)
    print(format_summary(summary))
    print(f"{config.name}: {len(trials)}/{info['trials']} trial(s) finished "
          f"({info['finished_before']} before this run), "
          f"{info['workers']} at once at {info['trial_cpus']:g} CPU each on {info['cluster_cpus']:g} CPUs, "
          f"{info['warmed_cases']} lattice cases warmed in {info['warm_seconds']:.1f} s, "
          f"{info['seconds']:.1f} s in all", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in info['written'])}, trials/<trial>/run")
    return 0


def _exploit_config(args):
    """The ExploitConfig of `farm exploit`: the YAML file named, else one allocator (a registry name
    or a trained run folder) on --scenario, with the flags' budget."""
    from farm.alloc.allocators import allocator_names
    from farm.studies.exploit import ExploitConfig, load_exploit_config

    target = args.target
    if target.endswith((".yaml", ".yml")):
        for flag in ("scenario", "seeds", "steps", "information"):
            if getattr(args, flag) is not None:
                raise CliError(f"--{flag}: give it in the config file {target}, not as a flag")
        return load_exploit_config(target)
    if args.scenario is None:
        raise CliError("--scenario: name the map to exploit the allocator on (farm exploit ALLOCATOR --scenario S)")
    run = Path(target)
    if target not in allocator_names() and not run.is_dir():
        raise CliError(f"target: {target!r} is no allocator of the registry, run folder or exploit YAML "
                       f"(allocators: {', '.join(allocator_names())})")
    label = run.name if run.is_dir() else target
    learned = None
    if args.seeds != "none":
        seeds = [int(s) for s in _floats(args.seeds or "0,1,2", "--seeds")]
        from farm.studies.exploit.config import LearnedParams

        settings = dict(LearnedParams().settings)
        if args.steps is not None:
            settings["ppo.n_timesteps"] = args.steps
        learned = {"seeds": seeds, "settings": settings}
    information = (args.information or "follower").split(",")
    fields = {"name": f"exploit-{label}-{args.scenario}".replace("/", "_"), "scenarios": [args.scenario],
              "allocators": [] if run.is_dir() else [target], "runs": {args.scenario: str(run)} if run.is_dir() else {},
              "information": information, "learned": learned, "episodes": args.episodes, "exact": args.exact}
    if not fields["allocators"] and not fields["runs"]:
        raise CliError(f"target: {target} holds no run")
    from pydantic import ValidationError

    try:
        return ExploitConfig(**fields)
    except ValidationError as e:
        from farm.core.config import first_line

        raise CliError(first_line(e)) from None


def cmd_exploit(args) -> int:
    """`farm exploit CONFIG|ALLOCATOR --out DIR`: allocators against the drift law, the heuristic
    intruders, their exact best response and a learned one over seeds; the worst case and the drop."""
    from farm.studies.exploit import format_table, run_exploit

    config = _exploit_config(args)
    out = Path(args.out or f"results/exploit/{config.name}")
    with flags("out", "address", "workers", workers="num_cpus"):
        long, table, info = run_exploit(config, out, address=args.address, workers=args.workers,
                                        show_progress=not args.quiet)
    print(format_table(table))
    skipped = f"; exact search skipped on {', '.join(info['exact_skipped'])} (its tree exceeds max_nodes)" \
        if info["exact_skipped"] else ""
    print(f"{config.name}: {len(long)} (allocator, adversary) rows, {info['pairs_played']} pairs played and "
          f"{info['exact_searched']} exact searches this time, {info['seconds']:.1f} s{skipped}", file=sys.stderr)
    print(f"wrote {out / 'table.csv'}, table.md, exploit.csv")
    return 0


def cmd_robust(args) -> int:
    """`farm robust CONFIG --out DIR`: policy-space response oracles for the allocation game; each
    iteration's NashConv and the final meta-Nash mixtures (resumable)."""
    from farm.studies.robust import load_robust_config, run_robust

    config = load_robust_config(args.config)
    if args.seed is not None:
        whole("--seed", args.seed, error=CliError)
        config = config.model_copy(update={"seed": args.seed, "name": f"{config.name}_s{args.seed}"})
    out = Path(args.out or f"results/robust/{config.name}")
    with flags("out", "address", "workers", workers="num_cpus"):
        iterations, info = run_robust(config, out, address=args.address, workers=args.workers,
                                      show_progress=not args.quiet)
    for k, it in enumerate(iterations):
        print(f"iteration {k}: {len(it.allocators)} allocators x {len(it.intruders)} intruder policies, value "
              f"{it.value:.4f}, gains {it.gains['defenders']:+.4f} (defenders) {it.gains['intruders']:+.4f} "
              f"(intruders), NashConv {it.nash_conv:.4f}")
    print(f"{config.name}: {len(iterations)} iteration(s) ({info['iterations_before']} before this run), "
          f"{info['pairs_played']} pairs played this time, {info['seconds']:.1f} s", file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in info.get('files', []))}")
    return 0


def _cluster_options(p: argparse.ArgumentParser, workers_help: str) -> None:
    """--address, --workers and --quiet of a command that runs on Ray."""
    p.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    p.add_argument("--workers", type=int, help=workers_help)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def build_parser() -> argparse.ArgumentParser:
    """The `farm` argument parser, one subcommand per cmd_* function."""
    parser = _Parser(prog="farm", description="swarm-farm: swarm-to-swarm engagement planning and learning")
    parser.add_argument("--debug", action="store_true",
                        help=f"show the traceback of an error (also {DEBUG_ENV}=1)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    g = sub.add_parser("game", help="play one pursuit-evasion game and print capture times")
    src = g.add_argument_group("initial positions (default: sampled)")
    src.add_argument("--positions", help="JSON file {\"pursuers\": [[x, y], ...], \"evaders\": [[x, y], ...]}")
    src.add_argument("--pursuers", help="pursuer positions 'x,y;x,y;...'")
    src.add_argument("--evaders", help="evader positions 'x,y;x,y;...'")
    src.add_argument("--n-pursuers", type=int, help="sampled start: pursuers (default 3)")
    src.add_argument("--n-evaders", type=int, help="sampled start: evaders (default 1)")
    src.add_argument("--seed", type=int, help="sampled start: the game's seed (default 0)")
    _add_game_options(g)
    g.add_argument("--plot", help="write a PNG of the trajectories and Voronoi cells here")
    g.add_argument("--plot-times", help="times in s of the panels, e.g. '0,1,2' (default: start, middle, end)")
    g.add_argument("--animate", metavar="PATH", help="write an animation of the game here (.gif or .mp4)")
    g.add_argument("--frame-stride", type=int, metavar="K",
                   help="animate every K-th step (default: at most 120 frames)")
    g.add_argument("--fps", type=float, help="frames per second of --animate (default: real time, at least 1)")
    g.set_defaults(func=cmd_game)

    t = sub.add_parser("pe-table", help="the paper's Tables 1 and 2 with figures")
    t.add_argument("--games", type=int, default=50, help="Monte Carlo games per case")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", help="results folder (default results/pe-table; at other speeds "
                                 "results/pe-table-speeds-P-E)")
    t.add_argument("--format", choices=["csv", "parquet"], default="csv")
    t.add_argument("--no-figures", action="store_true")
    t.add_argument("--yes", action="store_true", help="run over the size limits (farm/games/sizes.py) anyway")
    _add_game_options(t, SPEED_FLAGS)
    t.set_defaults(func=cmd_pe_table)

    s = sub.add_parser("sweep", help="run a parametric Monte Carlo sweep on Ray (resumable)")
    s.add_argument("config", help="sweep YAML, e.g. configs/smoke.yaml")
    s.add_argument("--out", help="results folder (default results/sweeps/<name>)")
    s.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    s.add_argument("--workers", type=int, help="shards running at once (default: the cluster's CPUs)")
    s.add_argument("--metrics-port", type=int, help="local Ray only: Prometheus export port")
    s.add_argument("--no-ray", action="store_true", help="run the shards in this process, without Ray")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--yes", action="store_true", help="run a sweep over the size limits (farm/games/sizes.py) anyway")
    s.add_argument("--rebuild", action="store_true",
                   help="write a damaged or missing OUT/sweep.json again from CONFIG (its shards' sweep id is checked)")
    s.set_defaults(func=cmd_sweep)

    tb = sub.add_parser("table", help="fill the capture-time store (farm table CONFIG) or show it "
                                      "(farm table show CONFIG)")
    tb.add_argument("args", nargs="+", metavar="[show] CONFIG")
    tb.add_argument("--store", help="SQLite store (default: the config's `store`)")
    tb.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    tb.add_argument("--workers", type=int, help="local Ray only: CPUs")
    tb.add_argument("--plot-dir", help="where heatmaps go (default: next to the store, tables/)")
    tb.add_argument("--quiet", action="store_true")
    tb.add_argument("--yes", action="store_true", help="fill a table over the size limits (farm/games/sizes.py) anyway")
    tb.set_defaults(func=cmd_table)

    r = sub.add_parser("report", help="one self-contained HTML page of everything in a results folder")
    r.add_argument("results_dir")
    r.add_argument("-o", "--output", help="where the HTML goes (default RESULTS_DIR/report.html)")
    r.set_defaults(func=cmd_report)

    tr = sub.add_parser("train", help="train the TD3 allocator (rewards from the capture-time service)")
    tr.add_argument("config", help="training YAML, e.g. configs/train/paper_3x3_c1_0.yaml")
    tr.add_argument("--out", help="run folder (default results/runs/<name>)")
    tr.add_argument("--resume", action="store_true", help="go on from the run folder's last checkpoint")
    tr.add_argument("--timesteps", type=int, help="override the learner's n_timesteps (td3.n_timesteps, "
                                                  "ppo.n_timesteps or sac.n_timesteps)")
    tr.add_argument("--service", choices=["ray", "local"], help="override service.mode")
    tr.add_argument("--threads", type=int, help="override threads: torch threads while training (config default 1)")
    tr.add_argument("--quiet", action="store_true")
    tr.set_defaults(func=cmd_train)

    ev = sub.add_parser("eval", help="the trained policy against the baselines and the planners on the same "
                                     "seeded episodes")
    ev.add_argument("run_dir")
    ev.add_argument("--episodes", type=int, default=20)
    ev.add_argument("--seed", type=int, default=1000)
    ev.add_argument("--fidelity", choices=["service", "games"], default="service")
    ev.add_argument("--quiet", action="store_true", help="no progress bar (--fidelity games)")
    ev.add_argument("--animate", nargs="?", const="episode.gif", metavar="PATH",
                    help="also animate the trained allocator's first episode (.gif or .mp4, in the run folder; "
                         "default episode.gif); under --fidelity games with one engaged cell's game beside it")
    ev.add_argument("--scenario", help="evaluate on this suite scenario's map instead of the run's own (a CellPolicy "
                                       "acts on any map size); files go to RUN_DIR/scenarios/NAME/")
    ev.add_argument("--references", help="the baselines and planners to compare with, comma-separated, or 'none' "
                                         "(default: every one)")
    ev.add_argument("--repair", help="the trained allocator's output: 'none' (its network alone) or 'levels' "
                                     "(the level repair); default: the run's config's. Another than the run's "
                                     "own writes into repair_<value>/")
    ev.set_defaults(func=cmd_eval)

    su = sub.add_parser("suite", help="every policy on every scenario, same seeded episodes: a leaderboard")
    su.add_argument("config", help="suite YAML, e.g. configs/suite.yaml")
    su.add_argument("--out", required=True, help="results folder (leaderboard.csv, episodes.csv, leaderboard.png, "
                                                 "suite.json)")
    su.add_argument("--episodes", type=int, help="override episodes (seeded seed .. seed+episodes-1)")
    su.add_argument("--games", type=int, help="override the capture-time service's games per case of every "
                                              "scenario (env: {games: N}; quick runs)")
    _cluster_options(su, "evaluations running at once (default: the cluster's CPUs; a local Ray's CPUs)")
    su.set_defaults(func=cmd_suite)

    ex = sub.add_parser("experiments", help="TD3 over a grid of settings and seeds as Ray Tune trials on one "
                                            "capture-time service (resumable)")
    ex.add_argument("config", help="experiments YAML, e.g. configs/experiments/smoke.yaml")
    ex.add_argument("--out", required=True, help="results folder (trials.csv, summary.csv, trials/, tune/), or an "
                                                 "object-store URI such as s3://bucket/path (no shared file system "
                                                 "needed on a cluster)")
    _cluster_options(ex, "trials at once (default: the cluster's CPUs; a local Ray gets max(2, WORKERS) CPUs)")
    ex.set_defaults(func=cmd_experiments)

    xp = sub.add_parser("exploit", help="how far adapting intruders exploit allocators: drift, heuristics, the "
                                        "exact best response and a learned one (resumable)")
    xp.add_argument("target", help="an exploit YAML (e.g. configs/exploit/table.yaml), or one allocator: a registry "
                                   "name or a trained run folder, with --scenario")
    xp.add_argument("--scenario", help="the map (one allocator only)")
    xp.add_argument("--information", help="follower, simultaneous or both comma-separated (default follower)")
    xp.add_argument("--seeds", help="the learned best response's seeds, comma-separated (default 0,1,2), or none")
    xp.add_argument("--steps", type=int, help="the learned best response's PPO steps (default: the exploit config's)")
    xp.add_argument("--episodes", type=int, default=20, help="evaluation episodes, seeded 1000.. (default 20)")
    xp.add_argument("--exact", choices=("auto", "always", "never"), default="auto",
                    help="the exact search: where its tree fits (auto), everywhere, or not at all")
    xp.add_argument("--out", help="results folder (default results/exploit/NAME)")
    _cluster_options(xp, "tasks and trials at once (default: the cluster's CPUs)")
    xp.set_defaults(func=cmd_exploit)

    rb = sub.add_parser("robust", help="allocators that hold against adapting intruders: policy-space response "
                                       "oracles on the farm (resumable)")
    rb.add_argument("config", help="robust YAML, e.g. configs/robust/outnumbered_3x3.yaml")
    rb.add_argument("--seed", type=int, help="the loop's seed instead of the config's; the name gets _s<seed> "
                                             "(make robust runs seeds 0, 1 and 2)")
    rb.add_argument("--out", help="results folder (default results/robust/NAME)")
    _cluster_options(rb, "payoff rollouts and trials at once (default: the cluster's CPUs)")
    rb.set_defaults(func=cmd_robust)

    cl = sub.add_parser("claims", help="the paper's claims (a)-(c), measured on evaluated runs, or over an "
                                       "experiment's seeds")
    cl.add_argument("runs_dir", help="folder of run folders (e.g. results/runs), or an experiment folder "
                                     "(e.g. results/experiments/paper)")
    cl.add_argument("--c0", help=f"the C_capture = 0 run's folder name (default {CLAIM_RUNS[0]}, as make experiments "
                                 f"names it)")
    cl.add_argument("--c15", help=f"the C_capture = 1.5 run's folder name (default {CLAIM_RUNS[1]})")
    cl.add_argument("--points", type=int, nargs=2, metavar=("C0", "C15"),
                    help="an experiment folder's points of C_capture 0 and 1.5 (default: found from the trials' "
                         "configs)")
    cl.set_defaults(func=cmd_claims)
    return parser


def _ray_errors() -> tuple:
    """Ray's exception base class, if Ray was imported (a command that used no Ray raised none)."""
    exceptions = sys.modules.get("ray.exceptions")
    return (exceptions.RayError,) if exceptions is not None else ()


_NEGATIVE = re.compile(r"^-\.?\d")


def _join_negative_values(argv: list[str]) -> list[str]:
    """`--target -1,5` as `--target=-1,5`: argparse takes a value that starts with '-' for a
    flag unless it is a plain number, so coordinates like -1,5 would need the '='."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(str(token))
    return out


_WARNED: set[str] = set()


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Show a warning as one line `farm: warning: ...`, each text once per command."""
    if str(message) not in _WARNED:
        _WARNED.add(str(message))
        print(f"farm: warning: {message}", file=sys.stderr)


def _refuse_empty_values(parser: argparse.ArgumentParser, args) -> None:
    """CliError naming the flag (or argument) given an empty value (`--animate ''`, `--out ''`):
    a flag given is never read as left out, nor an empty path as the current folder."""
    chosen = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen.append(action.choices[args.command])
    for p in chosen:
        for action in p._actions:
            value = getattr(args, action.dest, None)
            if isinstance(value, str) and not value.strip():
                if action.option_strings:
                    name = max(action.option_strings, key=len)
                    raise CliError(f"{name}: an empty value; give one, or leave {name} out")
                raise CliError(f"{action.dest}: an empty value")


def main(argv=None) -> int:
    """Run the `farm` command line; returns the exit status (2 for bad input, one line on stderr).
    `farm --debug ...` (the flag anywhere) or SWARM_FARM_DEBUG=1 lets errors through with their traceback."""
    argv = _join_negative_values(sys.argv[1:] if argv is None else [str(x) for x in argv])
    debug = os.environ.get(DEBUG_ENV, "") not in ("", "0") or "--debug" in argv
    argv = [x for x in argv if x != "--debug"]  # --debug is taken before or after the subcommand
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.showwarning = _one_line_warning  # restored when the block ends
            parser = build_parser()
            args = parser.parse_args(argv)
            _refuse_empty_values(parser, args)
            return args.func(args)
    except KeyboardInterrupt:
        if debug:
            raise
        print("farm: interrupted", file=sys.stderr)
        return 130
    except SwarmFarmError as e:
        if debug:
            raise
        print(f"farm: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a file or folder the user named, or a cluster that does not answer
        if debug:
            raise
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"farm: error: {where}{e.strerror or str(e).splitlines()[0] or type(e).__name__}", file=sys.stderr)
        return 2
    except _ray_errors() as e:  # a Ray failure: its cause, in one line
        if debug:
            raise
        cause = getattr(e, "cause", None) or e
        text = str(cause).strip().splitlines()
        print(f"farm: error: Ray: {type(cause).__name__}: {text[-1] if text else ''}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
