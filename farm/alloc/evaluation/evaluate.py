"""`farm eval RUN_DIR`: a run's trained allocator beside every registered baseline and planner,
on the same seeded episodes (farm.alloc.evaluation.rollout), the tables and figures written into the run
folder (farm.alloc.training.runs); with fidelity "games", the same episodes again with every engaged
cell's game simulated (farm.alloc.evaluation.fidelity)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from farm.alloc.allocators import Spec, allocator_entry, allocator_names, make_allocator
from farm.alloc.evaluation.fidelity import evaluate_fidelity
from farm.alloc.evaluation.rollout import behaviour_pair, evaluate_policies, steps_table
from farm.alloc.game.plots import plot_behaviour_steps
from farm.alloc.training.runs import RunFolder
from farm.core.checks import whole
from farm.core.errors import ConfigError

__all__ = ["fidelity_lines", "RunEvaluation", "reference_specs", "allocators", "evaluate_trained", "evaluate_run",
           "FIDELITIES"]

FIDELITIES = ("service", "games")


@dataclass
class RunEvaluation:
    """What evaluate_run measured: table (rollout.measure_table by policy), per (per-episode
    rows), steps ({policy: list of (T, 3) per-step measures}), and under fidelity "games"
    games_table and differences (farm.alloc.evaluation.fidelity.evaluate_fidelity); games_per_case: the
    service's games per case; live: how the games were played (FreshGames.live())."""

    table: pd.DataFrame
    per: pd.DataFrame
    steps: dict
    games_per_case: int
    games_table: pd.DataFrame | None = None
    differences: pd.DataFrame | None = None
    live: dict | None = None
    animation: tuple | None = None  # (path, frames) of the episode's animation (animate)
    folder: Path | None = None  # where its tables and figures were written


def reference_specs() -> list[Spec]:
    """Every registered baseline and planner that is a reference (Entry.reference), in
    registration order, as specs (what a trained allocator is compared with)."""
    return [Spec(allocator_entry(name)) for name in allocator_names(("baseline", "planner"), references=True)]


def allocators(run: RunFolder, config, client, specs: list[Spec] | None = None, learned=None) -> dict:
    """{name: allocator}: the run's trained allocator (named by its algo, config.algo; learned:
    it, loaded already), then specs (default reference_specs()), each for config.env, planning
    on client's statistics."""
    learned = learned if learned is not None else make_allocator(config.algo, config.env, client, run=run.path)
    policies = {config.algo: learned}
    policies.update({s.name: s.make(config.env, client) for s in (reference_specs() if specs is None else specs)})
    return policies


def evaluate_trained(run: RunFolder, config, policies: dict, client, episodes: int, seed: int, *,
                     figures: bool = True):
    """policies (allocators()) on episodes seeded seed .. seed + episodes - 1 of config.env, their
    engagements answered by client; writes eval_table.csv, eval_episodes.csv, eval_steps.csv
    and, with figures, density_<policy>.png and behaviour_steps.png into the run folder.
    Returns (table, per, steps) (farm.alloc.evaluation.rollout.evaluate_policies)."""
    table, per, steps = evaluate_policies(config.env, policies, client, episodes, seed,
                                          out=run.path if figures else None)
    run.write_evaluation(table, per, steps_table(steps))
    if figures:
        plot_behaviour_steps(behaviour_pair(steps, table, config.algo), run.file("behaviour_steps.png"))
    return table, per, steps


def _allocator_config(run: RunFolder, run_dir):
    """The run's TrainConfig; ConfigError (one line naming run) for a run that trained the intruders."""
    config = run.read_config()
    if config.side == "intruders":
        raise ConfigError(f"run: {run_dir} trained the intruders (side: intruders), not an allocator; play it as the "
                          f"intruders of a config (intruders: learned, intruder_options: {{run: {run_dir}}})",
                          field="run")
    return config


def evaluate_run(run_dir, *, episodes: int = 20, seed: int = 1000, fidelity: str = "service",
                 scenario: str | None = None, references: list[str] | None = None,
                 animate=None, show_progress: bool = True, repair: str | None = None) -> RunEvaluation:
    """`farm eval`: evaluate a run folder's trained allocator (see the module doc) with the
    capture-time service of its config (service.mode local: in this process, the games of
    fidelity "games" too, no Ray). scenario: a suite scenario's name, to evaluate the run on
    that map instead of its own (a CellPolicy acts on any map size; the service's games and
    seed stay the run's), the tables and figures
    then written into the run's scenarios/<name>/. references: the baselines and planners to
    compare with, by name (default: every one; [] none). ConfigError (one line naming the
    field) for bad input, before any episode: not a run, a run of the intruders (side:
    intruders), episodes or seed not whole numbers
    >= 1 (>= 0), more episodes than memory holds the tables of (_check_memory), an unknown
    fidelity, scenario or reference, a model that cannot act on the
    scenario's map, a run folder the tables cannot be written into, an animate path that is not
    a .gif or .mp4. animate: also write an animation of the trained allocator's first episode
    there (farm.alloc.evaluation.animation; under fidelity "games" with one engaged cell's game inset),
    a path relative to the folder the tables go into. show_progress: fidelity "games" shows
    its steps, games and games/s on stderr (evaluate_fidelity). repair: the trained allocator's
    output, `none` (its network alone) or `levels` (farm.alloc.allocators.repair); None: the run's
    config's. One other than the run's own writes into repair_<value>/ of the folder the
    tables go into, so the run's own evaluation there is kept. An evaluation already in the
    folder the tables go into that holds a policy this one leaves out (references) is never
    written over: ConfigError naming references, before any episode."""
    run = RunFolder(run_dir)
    config = _on_scenario(_allocator_config(run, run_dir), scenario)
    _check_arguments(episodes, seed, fidelity, references)
    specs = None if references is None else [Spec(allocator_entry(name)) for name in references]
    _check_memory(episodes, 1 + len(reference_specs() if specs is None else specs), config.env.max_steps)
    learned = _trained_allocator(run, config, scenario, repair)
    folder, animate = _output_paths(run, config, scenario, repair, animate, references)
    if folder != run.path:
        run = RunFolder(folder)  # where this evaluation's files go
        run.path.mkdir(parents=True, exist_ok=True)
    return _evaluate(run, config, learned, specs, episodes, seed, fidelity, animate=animate,
                     map_name=scenario or config.name, show_progress=show_progress)


def _on_scenario(config, scenario: str | None):
    """config (a TrainConfig) with its env on scenario's map, the service's games and seed kept
    (as farm suite keeps them); config itself for scenario None. ConfigError for an unknown one."""
    from farm.alloc.game.scenarios import SCENARIOS, known_scenario

    if scenario is None:
        return config
    try:
        known_scenario(scenario)
    except ValueError as e:
        raise ConfigError(f"scenario: {e}", field="scenario") from None
    own = config.env
    return config.model_copy(update={"env": SCENARIOS[scenario].config(games=own.games, seed=own.seed)})


def _check_arguments(episodes, seed, fidelity, references) -> None:
    """ConfigError naming the field unless episodes is a whole number >= 1, seed one >= 0,
    fidelity one of FIDELITIES and references None or names of baselines and planners."""
    whole("episodes", episodes, 1)
    whole("seed", seed, 0)
    if fidelity not in FIDELITIES:
        raise ConfigError(f"fidelity: must be one of {', '.join(FIDELITIES)}, got {fidelity!r}", field="fidelity")
    choices = allocator_names(("baseline", "planner"))
    for name in references or []:
        if name not in choices:
            raise ConfigError(f"references: {name!r} is not a baseline or planner (choose from {', '.join(choices)}, "
                              f"or none)", field="references")


STEP_BYTES = 256  # an evaluated step in memory: its measures and its rows of eval_steps.csv's table (generous)
EPISODE_BYTES = 1024  # an evaluated episode beyond its steps: its summary and its row of eval_episodes.csv


def _check_memory(episodes: int, policies: int, max_steps: int) -> None:
    """ConfigError naming episodes when the evaluation's per-step and per-episode tables
    (STEP_BYTES, EPISODE_BYTES; every episode at max_steps steps) of `policies` allocators would
    need more than half of this machine's memory, before any episode."""
    from farm.games.sizes import memory_limit

    needed, limit = episodes * policies * (max_steps * STEP_BYTES + EPISODE_BYTES), memory_limit()
    if needed > limit:
        raise ConfigError(f"episodes: {episodes:,} episodes of {policies} allocators keep up to "
                          f"{needed / 2**30:,.1f} GiB of tables in memory, more than half of this machine's "
                          f"({limit / 2**30:,.1f} GiB); evaluate fewer", field="episodes")


def _trained_allocator(run: RunFolder, config, scenario: str | None, repair: str | None):
    """The run's trained allocator for config's map, with its output repaired as repair says,
    loaded before any service starts: a model.zip that cannot be loaded is one line. A model
    that does not fit the run's own map is a ConfigError naming run_dir (its config.yaml no longer
    says what was trained); one that does not fit a scenario's map names scenario."""
    try:
        return make_allocator(config.algo, config.env, None, run=run.path, repair=repair)
    except ConfigError as e:
        if scenario is not None or e.field != "scenario":
            raise
        raise ConfigError(f"run_dir: {run.path}'s config.yaml does not fit its model: {e.problem} (was config.yaml "
                          f"edited?)", field="run_dir") from None


def _output_paths(run: RunFolder, config, scenario: str | None, repair: str | None, animate,
                  references: list[str] | None = None):
    """(folder, animate): the folder this evaluation's tables and figures go into (the run's,
    its scenarios/<scenario>/, and repair_<repair>/ of that for a repair other than the run's
    own), and the animation's path in it (None without animate). Both are checked writable now,
    before any episode, so that a read-only run folder is found at once, not at the end; and
    the evaluation already there is checked to lose nothing (_check_kept of references)."""
    from farm.core.output import check_writable_folder

    folder = run.path if scenario is None else run.path / "scenarios" / scenario
    if repair is not None and repair != config.repair:
        folder = folder / f"repair_{repair}"  # the run's own evaluation stays where it is
    check_writable_folder(folder, "run_dir")
    _check_kept(folder, config.algo, references)
    if animate is not None:
        from farm.core.game_animation import check_animation_path
        from farm.core.output import check_writable_file

        animate = folder / check_animation_path(animate)
        check_writable_file(animate, "animate")
    return folder, animate


def _check_kept(folder: Path, algo: str, references: list[str] | None) -> None:
    """ConfigError naming references when folder's eval_table.csv holds the evaluation of a
    policy this one (the trained allocator algo and references, None: every reference) leaves
    out: it would be written over and lost. An unreadable table holds nothing to keep."""
    table = folder / "eval_table.csv"
    if not table.is_file():
        return
    try:
        held = [str(p) for p in pd.read_csv(table)["policy"]]
    except (OSError, UnicodeDecodeError, ValueError, LookupError):  # pandas' parser errors are ValueErrors
        return
    names = allocator_names(("baseline", "planner"), references=True) if references is None else references
    lost = [p for p in held if p not in [algo, *names]]
    if lost:
        raise ConfigError(f"references: {table} holds the evaluation of {', '.join(lost)} too, which this one "
                          f"would write over; evaluate them again (leave references out, or name them), or move "
                          f"that evaluation aside first", field="references")


def _evaluate(run: RunFolder, config, learned, specs, episodes: int, seed: int, fidelity: str, *, animate,
              map_name: str, show_progress: bool) -> RunEvaluation:
    """The evaluation, its files written into run: the trained allocator learned and the
    references of specs on the seeded episodes (evaluate_trained), under fidelity "games" the
    same episodes with every engaged cell's game played (evaluate_fidelity), and the animation of
    the trained allocator's first episode on map_name (with animate). The capture-time service is
    config's: with service.mode local, it and the games are in this process, no Ray."""
    from farm.alloc.training.config import store_of
    from farm.service.client import open_client

    settings = config.env.game_settings()
    mode = config.service.mode
    with open_client(settings, mode=mode, store=store_of(config), address=config.service.address) as client:
        policies = allocators(run, config, client, specs, learned=learned)
        table, per, steps = evaluate_trained(run, config, policies, client, episodes, seed)
        result = RunEvaluation(table, per, steps, settings.games, folder=run.path)
        if fidelity == "games":
            result.games_table, result.differences, result.live = evaluate_fidelity(
                config.env, policies, client, episodes, seed, in_process=mode == "local", show_progress=show_progress)
            run.write_fidelity(result.games_table, result.differences)
        if animate is not None:
            from farm.alloc.evaluation.animation import write_episode_animation
            from farm.alloc.evaluation.rollout import play

            episode = play(config.env, policies[config.algo], client, 1, seed, record_first=True)[0]
            title = f"{config.algo} on {map_name}, episode seed {seed}"
            result.animation = write_episode_animation(episode, animate, title,
                                                       settings=settings if fidelity == "games" else None)
    return result


def fidelity_lines(result: RunEvaluation) -> list[str]:
    """What fidelity "games" found, as lines: each policy's return under the games minus under
    the service, and the fraction captured within tau, game minus service, over the engagements."""
    import numpy as np

    from farm.core.stats import mean_ci95

    merged = result.table.merge(result.games_table, on="policy", suffixes=("_service", "_games"))
    live = result.live or {}
    lines = [f"live engagements: {live.get('games', 0)} games in {live.get('tasks', 0) or 'no'} Ray task(s) "
             f"({'in this process' if not live.get('tasks') else 'coarse tasks'}), "
             f"{live.get('games_per_second', float('nan')):.0f} games/s"] if live else []
    lines += ["return, games minus service: " + ", ".join(
        f"{r.policy} {r.return_mean_games - r.return_mean_service:+.3f}" for r in merged.itertuples())]
    if len(result.differences):
        d = (result.differences["game_frac_tau"] - result.differences["service_frac_tau"]).to_numpy(dtype=float)
        m, h = mean_ci95(d)
        lines.append(f"fraction captured within tau over {len(d)} engagements, game - service: "
                     f"mean {m:+.3f} ± {h:.3f} (95% CI over engagements, the service's values taken as fixed; "
                     f"they carry the sampling error of {result.games_per_case} games per case), "
                     f"mean |game - service| {np.abs(d).mean():.3f} (one game per engagement: mostly noise)")
    return lines
