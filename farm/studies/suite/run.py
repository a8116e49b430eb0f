"""`farm suite CONFIG --out DIR`: every allocator on every scenario, on the same seeded
episodes; a leaderboard with 95% CIs. docs/suite.md says how it runs (one service actor, the
lattice warmed first, one Ray task per (scenario, allocator)) and why 2 CPUs cannot deadlock."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pandas as pd

from farm.alloc.allocators import Spec, allocator_entry, make_allocator
from farm.alloc.game.config import INTRUDER_FIELDS, AllocConfig
from farm.alloc.game.lattice import lattice_groups, warm_lattices
from farm.alloc.game.scenarios import SCENARIOS
from farm.alloc.training.runs import RunFolder
from farm.core.checks import whole
from farm.core.errors import ConfigError
from farm.core.output import check_writable_folder
from farm.studies.suite.config import SuiteConfig
from farm.studies.suite.leaderboard import leaderboard, plot_leaderboard

__all__ = ["run_suite"]


def _run_folder(config: SuiteConfig, scenario: str, env: AllocConfig):
    """(algo, trained policy) of a scenario's run folder, or None when it is missing and missing
    runs are skipped; ConfigError (one line naming runs.<scenario>) otherwise, and for a run
    trained on another env, unless its policy is a CellPolicy (size-free: it acts on any map)."""
    run_dir = Path(config.runs[scenario])
    run = RunFolder(run_dir)
    field = f"runs.{scenario}"
    if not run.has_model():
        if config.skip_missing_runs:
            return None
        what = "does not exist" if not run_dir.exists() else "holds no trained model (model.zip)"
        raise ConfigError(f"{field}: {run_dir} {what}; train it (farm train configs/train/suite_{scenario}.yaml "
                          f"--out {run_dir}) or set skip_missing_runs: true", field=field)
    try:
        trained_config = run.read_config()
    except ConfigError as e:
        raise ConfigError(f"{field}: {e}", field=field) from None
    ours, theirs = env.model_dump(), trained_config.env.model_dump()
    size_free = trained_config.learner.policy == "CellPolicy"  # its weights act on any map
    for name in ([] if size_free else ours):  # whatever intruders it trained against, it may meet others
        if name not in ("games", "seed", *INTRUDER_FIELDS) and ours[name] != theirs.get(name):
            raise ConfigError(f"{field}: {run_dir} was trained on another env ({name}: {theirs.get(name)!r}, "
                              f"the scenario's {ours[name]!r})", field=field)
    try:
        return trained_config.algo, make_allocator(trained_config.algo, env, None, run=run_dir)
    except ConfigError as e:
        raise ConfigError(f"{field}: {e}", field=field) from None


def _plan(config: SuiteConfig) -> tuple[dict[tuple, AllocConfig], list[tuple[tuple, Spec]], dict]:
    """(env settings by (scenario, intruder policy or None), [((scenario, intruders), allocator
    spec)] in leaderboard order, skipped runs)."""
    envs = {(name, intruders): config.env_of(name, intruders) for name in config.scenario_names()
            for intruders in config.intruder_axis()}
    specs = [Spec(allocator_entry(name), dict(config.planner_options.get(name, {})))
             for name in config.allocator_names()]
    jobs, skipped, trained = [], {}, {}
    for key, env in envs.items():
        scenario = key[0]
        jobs += [(key, spec) for spec in specs]
        if scenario in config.runs:
            if scenario not in trained:
                trained[scenario] = _run_folder(config, scenario, env)
            if trained[scenario] is None:
                skipped[scenario] = config.runs[scenario]
            else:
                algo, policy = trained[scenario]
                jobs.append((key, Spec(allocator_entry(algo), {"policy": policy})))
    return envs, jobs, skipped


def run_suite(config: SuiteConfig, out, *, episodes: int | None = None, address: str | None = None,
              workers: int | None = None, show_progress: bool = True, warm: bool = True) -> tuple[pd.DataFrame, dict]:
    """Run a suite into the folder out (docs/suite.md); returns (leaderboard, info).

    episodes: replaces the config's; address: a Ray cluster to join (default $RAY_ADDRESS,
    else a local Ray of `workers` CPUs, 2 by default); workers: evaluation tasks in flight
    (default the cluster's CPUs); warm: False skips computing the lattice first (the tests
    use it to make evaluations miss). info: wall seconds of the warm-up and the evaluations,
    cases warmed, tasks, the workers used, skipped runs.
    ConfigError (one line naming the field) for bad input, before Ray starts: the folder, the
    episodes, the run folders, the planners' option values (each planner is built once to
    check them). A project error raised in a task (e.g. a planner's InputError) is raised
    here as the same class, one line naming the scenario and the policy.
    """
    from farm.service.store import default_store_path

    config, out = _checked(config, out, episodes, workers)
    envs, jobs, skipped = _plan(config)
    _check_planners(jobs, envs)
    for scenario, path in skipped.items():
        print(f"farm suite: runs.{scenario}: {path} holds no trained model yet; skipped", file=sys.stderr)
    store = Path(config.store or default_store_path())
    tasks = matchup_tasks([_cost(envs[key]) for key, _ in jobs], config.episodes)
    info: dict = {"tasks": len(tasks), "cells": len(jobs), "skipped_runs": skipped, "warmed_cases": 0}
    t0 = time.perf_counter()
    results = _play_matchups(config, envs, jobs, tasks, store, info, address=address, workers=workers, warm=warm,
                             show_progress=show_progress)
    axis = config.intruders is not None
    rows = [{"scenario": jobs[j][0][0], **({"intruders": jobs[j][0][1]} if axis else {}), "policy": jobs[j][1].name,
             **row} for j, first, _ in sorted(tasks) for row in results[j, first]]
    per = pd.DataFrame(rows)
    board = leaderboard(per)
    info["seconds"] = time.perf_counter() - t0
    _write_suite(config, out, board, per, envs, jobs, skipped, store, info)
    return board, info


def _checked(config: SuiteConfig, out, episodes: int | None, workers: int | None) -> tuple[SuiteConfig, Path]:
    """(config, out as a Path), config's episodes replaced by episodes when given, once episodes,
    workers and out are checked: ConfigError naming the field, before the lattice and the
    episodes, not after them (out must be a folder that can be written, or not exist yet)."""
    from farm.runtime import check_workers

    if episodes is not None:
        whole("episodes", episodes, 1)
        config = config.model_copy(update={"episodes": episodes})
    check_workers(workers)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"out: {out} exists and is not a folder", field="out")
    check_writable_folder(out, "out")
    return config, out


def _play_matchups(config: SuiteConfig, envs: dict, jobs: list, tasks: list, store: Path, info: dict, *,
                   address: str | None, workers: int | None, warm: bool, show_progress: bool) -> dict:
    """Each task's episode rows, {(matchup, first episode): [row, ...]}, played by Ray tasks that
    share one capture-time service actor over store: the lattice warmed first (unless warm is
    False), then the tasks, the largest maps first so that the last to finish are short ones, at
    most tasks_in_flight at a time. Adds warmed_cases, warm_seconds, workers and
    evaluation_seconds to info."""
    from farm.core.progress import GameProgress
    from farm.runtime import bounded, starts_local_ray, task_result, tasks_in_flight
    from farm.service.client import open_client

    first = next(iter(envs.values()))
    starts_ray = starts_local_ray(address)
    t0 = time.perf_counter()
    with open_client(first.game_settings(), mode="ray", store=store, address=address,
                     num_cpus=workers if starts_ray else None) as client:
        import ray

        from farm.studies.suite.tasks import remote_suite_matchup

        actor = client.backend.actor
        if warm:
            info["warmed_cases"] = warm_lattices(client, lattice_groups(envs.values()), show_progress)
        info["warm_seconds"] = time.perf_counter() - t0
        cpus = int(ray.cluster_resources().get("CPU", 1))
        n = tasks_in_flight(workers, cpus, address)
        info["workers"] = n
        order = sorted(tasks, key=lambda t: -_cost(envs[jobs[t[0]][0]]))
        results: dict[tuple[int, int], list[dict]] = {}
        bar = GameProgress(len(jobs) * config.episodes, enabled=show_progress, desc="episodes", unit="episode")
        t1 = time.perf_counter()
        try:
            def submit(task):
                j, first, count = task
                key, spec = jobs[j]
                return remote_suite_matchup.remote(envs[key], spec, actor, count, config.seed + first)

            for (j, first, count), ref in bounded(submit, order, n):
                results[j, first] = [{**row, "episode": first + row["episode"]}
                                     for row in task_result(ref, f"{_shown(jobs[j][0])}, {jobs[j][1].name}")]
                bar.update(count)
        finally:
            bar.close()
        info["evaluation_seconds"] = time.perf_counter() - t1
    return results


def _write_suite(config: SuiteConfig, out: Path, board: pd.DataFrame, per: pd.DataFrame, envs: dict, jobs: list,
                 skipped: dict, store: Path, info: dict) -> None:
    """The suite's files in out: leaderboard.csv, episodes.csv, leaderboard.png and suite.json."""
    from farm.core.output import write_table

    out.mkdir(parents=True, exist_ok=True)
    write_table(board, out / "leaderboard", "csv")
    write_table(per, out / "episodes", "csv")
    plot_leaderboard(board, out / "leaderboard.png", title=f"{config.name}: intruder mass eliminated "
                     f"(mean and 95% CI over {config.episodes} episodes)")
    _write_manifest(config, envs, jobs, skipped, store, info, out / "suite.json")


def _check_planners(jobs: list, envs: dict) -> None:
    """Build every (scenario, planner) once, before Ray starts, so that a bad planner option
    is one line (ConfigError naming planner_options.<planner>), not a failed task
    (farm.alloc.allocators.check_options)."""
    from farm.alloc.allocators import ALLOCATORS

    for key, spec in jobs:
        if not spec.entry.options():
            continue
        try:
            ALLOCATORS.check_options(spec.name, spec.options, envs[key], f"planner_options.{spec.name}")
        except ConfigError as e:
            raise ConfigError(f"{e} (scenario {key[0]})") from None


def _shown(key: tuple) -> str:
    """A matchup's map as messages name it: the scenario, and the intruders of an adversary axis."""
    scenario, intruders = key
    return scenario if intruders is None else f"{scenario} against {intruders}"


def _cost(env: AllocConfig) -> float:
    """An episode's rough relative cost: cells times steps."""
    return env.grid_size ** 2 * env.max_steps


TASK_COST = 16 ** 2 * 16  # a task holds at least a 16 x 16 episode's cells x steps


def matchup_tasks(costs: list[float], episodes: int) -> list[tuple[int, int, int]]:
    """Each (scenario, allocator) matchup's episodes cut into Ray tasks: (matchup, first episode,
    episodes) of each, in matchup order. costs: each matchup's cost of one episode (_cost). A task
    holds as few episodes as make up TASK_COST (an episode costing more is a task of its
    own), the matchup's episodes shared evenly between its tasks: small maps stay one task a
    matchup (a 3 x 3 episode takes milliseconds), and a 32 x 32 matchup, whose receding_horizon
    episodes take minutes each, runs on every worker and moves the progress bar an episode
    at a time. Episode k of a matchup is seeded seed + k whatever the cut, and is the same
    episode (farm.alloc.evaluation.rollout.play), so the cut changes no number."""
    tasks = []
    for matchup, cost in enumerate(costs):
        per_task = min(episodes, max(1, int(TASK_COST // max(cost, 1))))
        pieces = -(-episodes // per_task)
        bounds = [episodes * i // pieces for i in range(pieces + 1)]
        tasks += [(matchup, bounds[i], bounds[i + 1] - bounds[i]) for i in range(pieces)]
    return tasks


def _write_manifest(config: SuiteConfig, envs: dict, jobs: list, skipped: dict, store: Path, info: dict,
                    path: Path) -> None:
    from farm.core.output import atomic_write_bytes
    from workers import ENGINE_VERSION

    doc = {
        "name": config.name,
        "config": config.model_dump(mode="json", exclude_unset=True),
        "resolved": {
            "scenarios": {name: {"description": SCENARIOS[name].description, "gym_id": SCENARIOS[name].gym_id,
                                 "env": config.env_of(name).model_dump(mode="json")}
                          for name in config.scenario_names()},
            "policies": config.allocator_names(),
            "planner_options": config.planner_options,
            "runs": {key[0]: config.runs[key[0]] for key, spec in jobs if spec.entry.kind == "learned"},
            "skipped_runs": skipped,
            "episodes": config.episodes,
            "seeds": [config.seed, config.seed + config.episodes - 1],
            "store": str(store),
        },
        "engine_version": ENGINE_VERSION,
        "info": {k: v for k, v in info.items() if k != "skipped_runs"},
    }
    atomic_write_bytes(path, (json.dumps(doc, indent=2) + "\n").encode())
