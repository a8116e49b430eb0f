"""`farm suite CONFIG --out DIR`: every policy on every scenario, on the same seeded episodes;
a leaderboard with 95% CIs.

Config (configs/suite.yaml; every field optional):

    name: suite
    scenarios: [paper_3x3_c1_0, outnumbered_3x3]   # farm.alloc.scenarios.SCENARIOS; default: all
    policies: [stay_at_base, intercept]            # baselines and planners by name; default: all
                                                   # of farm.alloc.baselines.BASELINES and
                                                   # farm.alloc.planners.PLANNERS
    planner_options: {receding_horizon: {horizon: 3}}   # keyword arguments of a planner
    episodes: 10                                   # episode k is seeded seed + k, for every policy
    seed: 1000
    store: results/capture_times.sqlite            # the capture-time store (default: the user's)
    env: {games: 16}                               # AllocConfig settings replacing every scenario's
    runs: {paper_3x3_c1_0: results/runs/suite_paper_3x3_c1_0}   # trained TD3 runs, as policy `td3`
    skip_missing_runs: false                       # true: a run folder without model.zip is skipped

Relative paths (store, runs) are relative to the working folder, as in every farm config.
Bad input is one line naming the field, the bad value and the choices (ConfigError): an
unknown key, scenario, policy or planner option, a run of a scenario the suite does not
run, a setting a scenario refuses. A run folder named under `runs` must hold a trained model
(model.zip) whose env is the scenario's (the service's sampling, `games` and `seed`, may
differ); a missing one is one line naming it, unless `skip_missing_runs: true`, which skips
it, says so on stderr and lists it in suite.json (`skipped_runs`): configs/suite.yaml names
the README leaderboard's runs, results/runs/suite_<scenario>, that way, so it runs before
every run is trained.

How it runs (run_suite), on a local Ray or a cluster (farm.runtime.ray_cluster):
1. One capture-time service actor, the store's (farm.service.actor.get_service), serves every
   scenario: the service's keys hold every game setting, so scenarios of other settings
   (faster intruders) never share a value by mistake, and scenarios of the same settings share
   their games. Every scenario uses `team_sizes: lattice` (farm.alloc.scenarios), so the
   games a scenario can meet are known up front: each scenario's lattice
   (farm.alloc.train.lattice_pairs) is computed first, all scenarios' pairs at once through
   `client.warm` (the service computes them as Ray tasks, in parallel).
2. Each (scenario, policy) is one Ray task (farm.tasks._remote_suite_cell: coarse, all its
   episodes), at most `workers` in flight (farm.runtime.bounded; default the cluster's CPUs),
   the largest maps first. Each task builds its own CaptureTimeClient on the ONE shared
   service actor (its handle is the task's argument), builds its policy, and runs
   evaluate_cell: the episodes seeded seed .. seed + episodes - 1, the same for every policy,
   timing the policy's predict() alone.

Why this cannot deadlock on 2 CPUs: an evaluation task holds a CPU, and a game the service
has to compute is itself a Ray task needing a CPU, so two evaluation tasks on two CPUs could
seem to starve the games they wait for. They do not: a task blocked in ray.get (the client
waiting for the actor's answer) releases its CPU to Ray's scheduler until ray.get returns, so
the service's game tasks are scheduled on the CPUs the waiting tasks lent; the service actor
itself holds no CPU (num_cpus=0). And the lattice is warmed before any evaluation starts, so
in a normal run the evaluations never miss at all. tests/test_suite.py runs evaluations on a
cold store without warming on a 2-CPU Ray, every miss computed while both CPUs' tasks wait.

Written into DIR (existing files of a suite are replaced; other results in DIR stay):
- leaderboard.csv: one row per (scenario, policy), in the config's order (td3 last):
  scenario, policy, episodes, then return, eliminated, breached and coverage each as
  `<m>_mean` and `<m>_ci95` (the half-width of the 95% t interval over episodes; NaN for
  one episode), and seconds_per_step (mean wall seconds of one predict() call, timed inside
  the task);
- episodes.csv: one row per (scenario, policy, episode): seed, return, eliminated, breached,
  length, coverage, engaged, defenders_per_engaged (farm.alloc.evaluate.run_episode),
  steps, predict_seconds, and intruders_start: the intruders' densities of the right-most
  column the policy observed at the start, rows top to bottom, space-separated;
- leaderboard.png: the intruder mass eliminated per scenario, one bar per policy, 95% CI bars;
- suite.json: the config as given and as resolved (every scenario's full env settings, the
  policies, the runs used and skipped), the seeds, the engine version, timings.
"""

from __future__ import annotations

import inspect
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pydantic import Field, ValidationError, field_validator, model_validator

from farm.alloc.baselines import BASELINES
from farm.alloc.config import AllocConfig
from farm.alloc.scenarios import SCENARIOS
from farm.config import ConfigError, Strict, first_line, load_yaml_model, refuse_unknown_keys

__all__ = ["SuiteConfig", "load_suite_config", "available_policies", "PolicySpec", "build_policy", "evaluate_cell",
           "run_suite", "leaderboard", "plot_leaderboard", "format_leaderboard", "MEASURES", "TD3"]

MEASURES = ("return", "eliminated", "breached", "coverage")  # the leaderboard's columns, each mean and ci95
TD3 = "td3"  # the policy name of a trained run


def _planners() -> dict:
    """farm.alloc.planners.PLANNERS."""
    from farm.alloc.planners import PLANNERS

    return PLANNERS


def available_policies() -> list[str]:
    """The policy names a suite may list: every baseline, then every planner."""
    return [*BASELINES, *_planners()]


def _choices(names) -> str:
    return ", ".join(names) if names else "none"


class SuiteConfig(Strict):
    """A `farm suite` config (see the module doc); ConfigError or ValidationError, one line
    naming the field, the bad value and the choices, for bad input."""

    name: str = Field("suite", min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    scenarios: list[str] | None = None  # None: every scenario
    policies: list[str] | None = None  # None: every baseline and every planner
    planner_options: dict[str, dict[str, Any]] = {}
    episodes: int = Field(10, ge=1, le=100_000)
    seed: int = Field(1000, ge=0)
    store: str | None = None  # None: farm.service.store.default_store_path()
    env: dict[str, Any] = {}  # AllocConfig settings replacing every scenario's
    runs: dict[str, str] = {}  # scenario -> TD3 run folder
    skip_missing_runs: bool = False

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data):
        return refuse_unknown_keys(cls, data, "a suite")

    @field_validator("scenarios")
    @classmethod
    def _known_scenarios(cls, v):
        if v is None:
            return v
        if not v:
            raise ValueError(f"must name at least one scenario (choose from {_choices(SCENARIOS)})")
        for name in v:
            if name not in SCENARIOS:
                raise ValueError(f"unknown scenario {name!r} (choose from {_choices(SCENARIOS)})")
        _no_repeats(v)
        return v

    @field_validator("policies")
    @classmethod
    def _known_policies(cls, v):
        if v is None:
            return v
        choices = available_policies()
        if not v:
            raise ValueError(f"must name at least one policy (choose from {_choices(choices)})")
        for name in v:
            if name not in choices:
                hint = "; trained runs come from `runs`" if name == TD3 else ""
                raise ValueError(f"unknown policy {name!r} (choose from {_choices(choices)}){hint}")
        _no_repeats(v)
        return v

    @model_validator(mode="after")
    def _consistent(self):
        scenarios = self.scenario_names()
        for name, path in self.runs.items():
            if name not in scenarios:
                raise ValueError(f"runs.{name}: not a scenario of this suite, got {name!r} "
                                 f"(choose from {_choices(scenarios)})")
            if not path.strip():
                raise ValueError(f"runs.{name}: an empty folder name")
        policies = self.policy_names()
        planners = [name for name in policies if name in _planners()]
        for name, options in self.planner_options.items():
            if name not in planners:
                raise ValueError(f"planner_options.{name}: {name!r} is not a planner of this suite "
                                 f"(choose from {_choices(planners)})")
            params = inspect.signature(_planners()[name]).parameters
            allowed = [p for p in params if p not in ("config", "client")]
            for option in options:
                if option not in allowed:
                    raise ValueError(f"planner_options.{name}: unknown option {option!r} "
                                     f"(choose from {_choices(allowed)})")
        for name in scenarios:
            self.env_of(name)
        return self

    def scenario_names(self) -> list[str]:
        """The scenarios run, in order (every scenario when the config names none)."""
        return list(self.scenarios) if self.scenarios is not None else list(SCENARIOS)

    def policy_names(self) -> list[str]:
        """The baselines and planners run, in order (all of them when the config names none)."""
        return list(self.policies) if self.policies is not None else available_policies()

    def env_of(self, scenario: str) -> AllocConfig:
        """The env settings of one scenario in this suite: the scenario's, `env` replacing them.

        ValueError (one line, `env.<field>: ...`, naming the scenario) for a setting refused.
        """
        try:
            return SCENARIOS[scenario].config(**self.env)
        except ValidationError as e:
            raise ValueError(f"env.{first_line(e)} (in scenario {scenario})") from None


def _no_repeats(names: list[str]) -> None:
    seen = set()
    for name in names:
        if name in seen:
            raise ValueError(f"{name!r} is named twice")
        seen.add(name)


def load_suite_config(path) -> SuiteConfig:
    """Read and validate a suite YAML; ConfigError of one line naming the file and the field."""
    return load_yaml_model(path, SuiteConfig, "suite")


# ----------------------------------------------------------------------------- policies
PolicySpec = tuple  # (kind, name, payload): ("baseline", name, None), ("planner", name, options), ("td3", "td3", policy)


def build_policy(spec: PolicySpec, config: AllocConfig, client):
    """The allocator of a policy spec, with predict(obs, deterministic=True) -> (action, state).

    spec: ("baseline", name, None) makes BASELINES[name](grid_size); ("planner", name, options)
    makes PLANNERS[name](config, client, **options); ("td3", "td3", policy) is a trained SB3
    policy (model.policy), used as it is.
    """
    kind, name, payload = spec
    if kind == "baseline":
        return BASELINES[name](config.grid_size)
    if kind == "planner":
        return _planners()[name](config, client, **(payload or {}))
    if kind == TD3:
        return payload
    raise ValueError(f"policy: unknown kind {kind!r}")


class _Timed:
    """A policy whose predict() calls are timed and whose first observation of an episode is kept."""

    def __init__(self, policy):
        self.policy = policy
        self.seconds = 0.0
        self.calls = 0
        self.first_obs = None

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if self.first_obs is None:
            self.first_obs = np.array(obs, copy=True)
        t0 = time.perf_counter()
        out = self.policy.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out


def evaluate_cell(config: AllocConfig, spec: PolicySpec, client, episodes: int, seed: int) -> list[dict]:
    """One (scenario, policy) of the suite: the policy on episodes seeded seed .. seed +
    episodes - 1 (farm.alloc.evaluate.run_episode); returns one dict per episode.

    config: the scenario's env settings; spec: see build_policy; client: the
    CaptureTimeClient answering the engagements. Each dict holds episode, seed, the episode's
    summary (return, eliminated, breached, length, coverage, engaged,
    defenders_per_engaged), steps and predict_seconds (wall seconds in the policy's
    predict(), summed over the episode's steps), and intruders_start (the right-most
    column's intruder densities the policy first observed, rows top to bottom, as text).
    """
    from farm.alloc.env import SwarmAllocationEnv
    from farm.alloc.evaluate import run_episode

    env = SwarmAllocationEnv(config, client=client)
    policy = _Timed(build_policy(spec, config, client))
    n = config.grid_size
    rows = []
    try:
        for k in range(episodes):
            policy.seconds, policy.calls, policy.first_obs = 0.0, 0, None
            summary, _, _ = run_episode(env, policy, seed + k)
            start = policy.first_obs[n * n:].reshape(n, n)[:, -1]
            rows.append({"episode": k, "seed": seed + k, **summary, "steps": policy.calls,
                         "predict_seconds": policy.seconds,
                         "intruders_start": " ".join(repr(float(x)) for x in start)})
    finally:
        env.close()
    return rows


# ----------------------------------------------------------------------------- the run
def _run_folder(config: SuiteConfig, scenario: str, env: AllocConfig):
    """The TD3 policy of a scenario's run folder, or None when it is missing and missing runs
    are skipped; ConfigError (one line naming runs.<scenario>) otherwise."""
    from farm.alloc.evaluate import load_policy
    from farm.alloc.train import load_train_config

    run_dir = Path(config.runs[scenario])
    field = f"runs.{scenario}"
    if not (run_dir / "model.zip").exists():
        if config.skip_missing_runs:
            return None
        what = "does not exist" if not run_dir.exists() else "holds no trained model (model.zip)"
        raise ConfigError(f"{field}: {run_dir} {what}; train it (farm train configs/train/suite_{scenario}.yaml "
                          f"--out {run_dir}) or set skip_missing_runs: true")
    if not (run_dir / "config.yaml").exists():
        raise ConfigError(f"{field}: {run_dir} is not a training run (no config.yaml)")
    try:
        trained = load_train_config(run_dir / "config.yaml").env
    except ConfigError as e:
        raise ConfigError(f"{field}: {e}") from None
    ours, theirs = env.model_dump(), trained.model_dump()
    for name in ours:
        if name not in ("games", "seed") and ours[name] != theirs.get(name):
            raise ConfigError(f"{field}: {run_dir} was trained on another env ({name}: {theirs.get(name)!r}, "
                              f"the scenario's {ours[name]!r})")
    try:
        return load_policy(run_dir).policy
    except ConfigError as e:
        raise ConfigError(f"{field}: {e}") from None


def _plan(config: SuiteConfig) -> tuple[dict[str, AllocConfig], list[tuple[str, PolicySpec]], dict]:
    """(env settings by scenario, [(scenario, policy spec)] in leaderboard order, skipped runs)."""
    envs = {name: config.env_of(name) for name in config.scenario_names()}
    planners = _planners()
    specs = [("planner" if name in planners else "baseline", name,
              dict(config.planner_options.get(name, {})) if name in planners else None)
             for name in config.policy_names()]
    jobs, skipped = [], {}
    for scenario, env in envs.items():
        jobs += [(scenario, spec) for spec in specs]
        if scenario in config.runs:
            policy = _run_folder(config, scenario, env)
            if policy is None:
                skipped[scenario] = config.runs[scenario]
            else:
                jobs.append((scenario, (TD3, TD3, policy)))
    return envs, jobs, skipped


def _lattice_by_settings(envs: dict[str, AllocConfig]) -> list[tuple[AllocConfig, list[tuple[int, int]]]]:
    """Each distinct service setting's lattice pairs over the scenarios having it (a scenario
    whose team_sizes an `env` override made exact has no lattice to warm)."""
    from farm.alloc.train import lattice_pairs

    groups: dict = {}
    for env in envs.values():
        if env.team_sizes != "lattice":
            continue
        digest = env.service_settings().key(1, 1).settings_digest()
        _, pairs = groups.setdefault(digest, (env, set()))
        pairs.update(lattice_pairs(env))
    return [(env, sorted(pairs)) for env, pairs in groups.values()]


def run_suite(config: SuiteConfig, out, *, episodes: int | None = None, address: str | None = None,
              workers: int | None = None, show_progress: bool = True, warm: bool = True) -> tuple[pd.DataFrame, dict]:
    """Run a suite into the folder out (see the module doc); returns (leaderboard, info).

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
    from farm.output import write_table
    from farm.progress import GameProgress
    from farm.runtime import bounded, connected
    from farm.service.lookup import CaptureTimeClient, open_client
    from farm.service.store import default_store_path

    if episodes is not None:
        if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
            raise ConfigError(f"episodes: must be a whole number >= 1, got {episodes!r}")
        config = config.model_copy(update={"episodes": episodes})
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ConfigError(f"num_cpus: workers must be a whole number >= 1, got {workers!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"out: {out} exists and is not a folder")
    envs, jobs, skipped = _plan(config)
    _check_planners(jobs, envs)
    for scenario, path in skipped.items():
        print(f"farm suite: runs.{scenario}: {path} holds no trained model yet; skipped", file=sys.stderr)
    store = Path(config.store or default_store_path())
    first = next(iter(envs.values()))
    joined = bool(address or os.environ.get("RAY_ADDRESS"))
    starts_ray = not joined and not connected()
    info: dict = {"tasks": len(jobs), "skipped_runs": skipped, "warmed_cases": 0}
    t0 = time.perf_counter()
    with open_client(first.service_settings(), mode="ray", store=store, address=address,
                     num_cpus=workers if starts_ray else None) as client:
        import ray

        from farm.tasks import _remote_suite_cell

        actor = client.backend.actor
        if warm:
            groups = _lattice_by_settings(envs)
            total = sum(len(pairs) for _, pairs in groups)
            bar = GameProgress(total, enabled=show_progress, desc="capture-time lattice", unit="case")
            try:
                for env, pairs in groups:
                    CaptureTimeClient(env.service_settings(), service=actor).warm(pairs, progress=bar.update)
            finally:
                bar.close()
            info["warmed_cases"] = total
        info["warm_seconds"] = time.perf_counter() - t0
        cpus = int(ray.cluster_resources().get("CPU", 1))
        n = max(1, min(workers or cpus, cpus) if not joined else (workers or cpus))
        info["workers"] = n
        # The largest maps first, so that the last tasks to finish are short ones.
        order = sorted(range(len(jobs)), key=lambda j: -_cost(envs[jobs[j][0]]))
        results: dict[int, list[dict]] = {}
        bar = GameProgress(len(jobs) * config.episodes, enabled=show_progress, desc="episodes", unit="episode")
        t1 = time.perf_counter()
        try:
            def submit(j):
                scenario, spec = jobs[j]
                return _remote_suite_cell.remote(envs[scenario], spec, actor, config.episodes, config.seed)

            for j, ref in bounded(submit, order, n):
                results[j] = _result(ray, ref, *jobs[j])
                bar.update(config.episodes)
        finally:
            bar.close()
        info["evaluation_seconds"] = time.perf_counter() - t1
    rows = [{"scenario": jobs[j][0], "policy": jobs[j][1][1], **row} for j in range(len(jobs)) for row in results[j]]
    per = pd.DataFrame(rows)
    board = leaderboard(per)
    info["seconds"] = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    write_table(board, out / "leaderboard", "csv")
    write_table(per, out / "episodes", "csv")
    plot_leaderboard(board, out / "leaderboard.png", title=f"{config.name}: intruder mass eliminated "
                     f"(mean and 95% CI over {config.episodes} episodes)")
    _write_manifest(config, envs, jobs, skipped, store, info, out / "suite.json")
    return board, info


class _Unasked:
    """A capture-time backend for building planners to check their options: never asked."""

    repeatable = True

    def get_many(self, keys, estimate=False):
        raise RuntimeError("a planner asked for statistics while being built")

    def warm(self, keys, progress=None):
        raise RuntimeError("a planner asked for statistics while being built")


def _check_planners(jobs: list, envs: dict) -> None:
    """Build every (scenario, planner) once, before Ray starts, so that a bad planner option
    is one line (ConfigError naming planner_options.<planner>), not a failed task."""
    from farm.errors import SwarmFarmError
    from farm.service.lookup import CaptureTimeClient

    for scenario, spec in jobs:
        if spec[0] != "planner":
            continue
        client = CaptureTimeClient(envs[scenario].service_settings(), backend=_Unasked())
        try:
            build_policy(spec, envs[scenario], client)
        except (SwarmFarmError, TypeError, ValueError) as e:
            problem = str(e).removeprefix(f"{spec[1]}: ")
            raise ConfigError(f"planner_options.{spec[1]}: {problem} (scenario {scenario})") from None


def _result(ray, ref, scenario: str, spec: PolicySpec) -> list[dict]:
    """A task's rows; a project error it raised comes back as that error, one line naming the
    scenario and the policy (not Ray's wrapper with the worker's traceback)."""
    from farm.errors import SwarmFarmError

    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = getattr(e, "cause", None)
        if not isinstance(cause, SwarmFarmError):
            raise
        try:
            error = type(cause)(f"{scenario}, {spec[1]}: {cause}")
        except Exception:  # an error class that is not made from one message
            error = cause
        raise error from None


def _cost(env: AllocConfig) -> float:
    """A task's rough relative cost: cells times steps."""
    return env.grid_size ** 2 * env.max_steps


def _write_manifest(config: SuiteConfig, envs: dict, jobs: list, skipped: dict, store: Path, info: dict,
                    path: Path) -> None:
    from workers import ENGINE_VERSION

    from farm.output import atomic_write_bytes

    doc = {
        "name": config.name,
        "config": config.model_dump(mode="json", exclude_unset=True),
        "resolved": {
            "scenarios": {name: {"description": SCENARIOS[name].description, "gym_id": SCENARIOS[name].gym_id,
                                 "env": env.model_dump(mode="json")} for name, env in envs.items()},
            "policies": config.policy_names(),
            "planner_options": config.planner_options,
            "runs": {scenario: config.runs[scenario] for scenario, spec in jobs if spec[0] == TD3},
            "skipped_runs": skipped,
            "episodes": config.episodes,
            "seeds": [config.seed, config.seed + config.episodes - 1],
            "store": str(store),
        },
        "engine_version": ENGINE_VERSION,
        "info": {k: v for k, v in info.items() if k != "skipped_runs"},
    }
    atomic_write_bytes(path, (json.dumps(doc, indent=2) + "\n").encode())


# ----------------------------------------------------------------------------- the leaderboard
def leaderboard(per: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, policy) of the per-episode rows, in their order of appearance.

    per: episodes.csv's columns (scenario, policy, return, eliminated, breached, coverage,
    steps, predict_seconds, ...). Returns columns scenario, policy, episodes, <m>_mean and
    <m>_ci95 for each m of MEASURES (farm.alloc.evaluate.mean_ci95 over episodes; NaN
    half-width for one episode), seconds_per_step (predict seconds over steps).
    """
    from farm.alloc.evaluate import mean_ci95

    rows = []
    for (scenario, policy), g in per.groupby(["scenario", "policy"], sort=False):
        row = {"scenario": scenario, "policy": policy, "episodes": len(g)}
        for m in MEASURES:
            x = g[m].to_numpy(dtype=float)
            x = x[np.isfinite(x)]
            row[f"{m}_mean"], row[f"{m}_ci95"] = mean_ci95(x) if len(x) else (math.nan, math.nan)
        steps = int(g["steps"].sum())
        row["seconds_per_step"] = float(g["predict_seconds"].sum()) / steps if steps else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def plot_leaderboard(board: pd.DataFrame, path, title: str = "intruder mass eliminated") -> Path:
    """The intruder mass eliminated per scenario, one bar per policy, 95% CI error bars; returns path.

    board: leaderboard()'s columns (scenario, policy, eliminated_mean, eliminated_ci95).
    """
    from farm.plots import new_figure, save_figure

    scenarios = list(dict.fromkeys(board["scenario"]))
    policies = list(dict.fromkeys(board["policy"]))
    width = 0.8 / len(policies)
    fig, axes = new_figure(figsize=(min(24.0, max(7.0, 3.0 + len(scenarios) * (0.3 + 0.16 * len(policies)))), 4.2))
    ax = axes[0, 0]
    colours = [f"C{k % 10}" for k in range(len(policies))]
    for k, policy in enumerate(policies):
        g = board[board["policy"] == policy].set_index("scenario").reindex(scenarios)
        x = np.arange(len(scenarios)) + (k - (len(policies) - 1) / 2) * width
        err = np.nan_to_num(g["eliminated_ci95"].to_numpy(dtype=float))
        ax.bar(x, g["eliminated_mean"].to_numpy(dtype=float), width, yerr=err, capsize=2, label=policy,
               color=colours[k])
    ax.set_xticks(range(len(scenarios)), scenarios, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("intruder mass eliminated")
    ax.set_ylim(0, 1.05)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
    fig.tight_layout()
    return save_figure(fig, path)


def format_leaderboard(board: pd.DataFrame) -> str:
    """The leaderboard as a text table: scenario, policy, eliminated and return as mean ± CI, s/step."""

    def pm(m, h):
        return f"{m:.3f} ± {h:.3f}" if math.isfinite(h) else f"{m:.3f}"

    view = pd.DataFrame({
        "scenario": board["scenario"], "policy": board["policy"], "episodes": board["episodes"],
        "eliminated": [pm(m, h) for m, h in zip(board["eliminated_mean"], board["eliminated_ci95"])],
        "breached": [pm(m, h) for m, h in zip(board["breached_mean"], board["breached_ci95"])],
        "return": [pm(m, h) for m, h in zip(board["return_mean"], board["return_ci95"])],
        "ms/step": [f"{1000 * s:.2f}" for s in board["seconds_per_step"]],
    })
    return view.to_string(index=False)
