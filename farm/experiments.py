"""`farm experiments CONFIG --out DIR`: many TD3 trainings as one Ray Tune experiment, over a
grid of settings and seeds, every trial evaluated against the baselines and the planners on
the same seeded episodes, all trials on ONE capture-time service.

Config (YAML; every key but `name`, `seeds` and one of `base`/`scenario` optional):

    name: smoke
    base: configs/train/tiny.yaml     # a training config (farm.alloc.train.TrainConfig) ...
    scenario: null                    # ... or a suite scenario's name (TrainConfig's defaults
                                      # beside it); at most one of the two, none when the grid
                                      # (or overrides) names `scenario`
    overrides: {env.team_sizes: lattice}   # dotted fields set in every trial
    grid: {env.c_capture: [0.0, 1.5]}      # dotted fields -> values: the cartesian product
    seeds: [0, 1]                     # each (point, seed) is one trial: TrainConfig.seed
    episodes: 10                      # evaluation episodes, seeded eval_seed .. eval_seed+episodes-1
    eval_seed: 1000
    store: results/capture_times.sqlite    # the shared store (default: the user's,
                                           # farm.service.store.default_store_path())

A dotted field names a TrainConfig field through its sections: `env.<AllocConfig field>`,
`td3.<TD3Params field>` (`td3.policy_kwargs.net_arch` too), `eval.freq`, `checkpoint_freq`,
`log_interval`. `name`, `seed`, `threads` and `service` are the experiment's own: every
trial is named `<name>-<trial>`, seeded from `seeds`, trains on one torch thread and uses
the experiment's service. Relative paths (base, store) are relative to the working folder.
Bad input is one line (ConfigError) naming the file and the field: an unknown key, an
unknown or reserved grid field, an empty list of values or of seeds, a point whose settings
a training config refuses (naming the point).

How it runs (run_experiment), on a local Ray or a cluster (farm.runtime.ray_cluster):
1. One capture-time service actor, the store's (farm.service.actor.get_service), for every
   trial. Points on `team_sizes: lattice` have their lattice computed first, all points' pairs
   at once (the service plays them as Ray tasks on every CPU, before any trial starts).
2. Each (point, seed) is one Ray Tune trial (ray.tune.Tuner, a function trainable,
   `_run_trial`), at most `workers` at once (default: the cluster's CPUs), on actors Tune
   reuses from trial to trial (a new actor's imports, torch's optimiser pulling in
   torch._dynamo, cost about 5 s; on the smoke grid about as much as the training). A trial trains
   with farm.alloc.train.train into DIR/trials/<trial>/run with `service.mode: ray`: inside
   the trial's actor the process is connected to Ray already, so farm.runtime.ray_cluster
   joins it (starts nothing) and get_service finds the running named actor. Then it
   evaluates the final model, the baselines and the planners on the same seeded episodes
   (farm.alloc.evaluate.evaluate_policies), writes DIR/trials/<trial>/result.json and
   reports it to Tune.
3. DIR/trials.csv and DIR/summary.csv are written from the trials' result.json files, then
   the paper's claims over the seeds (farm.alloc.claims.claims_over_seeds: DIR/claims.csv and
   claims_seeds.csv, when two points differ only in C_capture 0 and 1.5) and the learning
   curves over seeds (farm.experiments_results: DIR/learning_curves.png).

How the trials and the service's games share the CPUs. A Tune trial is an actor that holds
the resources it asked for as long as it lives, and Ray releases a worker's CPU while it
waits in ray.get only for a plain task's main thread, never for an actor (nor for the
thread a function trainable runs in). A trial waiting for the service's answer therefore
keeps its CPU, while the answer needs the service's shard tasks (farm.tasks, 1 CPU each;
the actor itself holds none). With a trial at 1 CPU, 2 trials on 2 CPUs and a cold store,
nothing could run the games both trials wait for: a deadlock. The mechanism here is a
reserved share: trials ask for `trial_cpus(C, K)` = min(1, (C - 1) / K) CPUs each (C the
cluster's CPUs, K the trials at once), so that K trials together leave at least one whole
CPU that only game tasks can take; on 2 CPUs, 2 trials of 0.5 CPU each and 1 CPU for the
games. This is a logical share: each trial still trains on one torch thread, so 2 trials
run on the 2 cores, and the game tasks mostly run while the trials wait for them (a trial
waiting is idle). A cluster of fewer than 2 CPUs is refused. On top of it, warming the
lattice first (step 1) means a lattice run meets no missing key at all once its trials
start. tests/test_experiments.py runs 2 trials at once on a 2-CPU Ray on a cold store
without warming (every engagement's game computed while both trials wait): about 20 s with
Ray's start. The same run with trials at 1 CPU each (trial_cpus replaced) made no step in 90 s:
both trials waited for their first engagement's games, and Ray had no CPU left to run them.

Resuming: DIR/experiment.json holds the config's digest; the same command again restores
the Tune experiment in DIR/tune (Tuner.can_restore / Tuner.restore, unfinished and errored
trials resumed), and a finished trial is never trained again: Tune does not rerun it, and a
trial that finds its result.json (written before its last report) reports it without
training. An unfinished trial resumes from the last checkpoint in its run folder (the model,
the replay buffer and the run's state: random generators, the env's episode, the evaluations
so far; farm train --resume's path, see farm.alloc.train) and ends as it would have without
the stop: its row of trials.csv equals an uninterrupted run's but for the timings and
resumed_from. The Tune checkpoint it reports after each checkpoint is a small marker naming
the steps, the files staying in the run folder (which therefore must be on storage every
node sees, on a multi-node cluster). A DIR holding another experiment (another digest), or
files that are not an experiment's, is refused in one line. FailureConfig(max_failures=2)
restarts a trial whose worker died. An experiment stopped by Ctrl+C (Tune saves its state)
ends in ExperimentError saying how many trials are unfinished; run the same command again.
tests/test_experiments.py kills (SIGKILL) a trial's worker after its checkpoint of step 150
of 300: Tune restarts the trial, which goes on from that checkpoint; and kills the driver
with the local Ray it started once one trial of two has finished and the other has a
checkpoint: the same command again leaves the finished trial's files untouched and resumes
the other from its checkpoint. In both, every row equals the uninterrupted run's but for the
timings and resumed_from.

Written into DIR:
- experiment.json: the config as given, its digest, every trial's key, point and seed;
- trials/<trial>/run: the run folder (model.zip, metrics.json, checkpoints/, best/, tb/, ...)
  with eval_table.csv; trials/<trial>/result.json: the trial's row of trials.csv;
- trials.csv: one row per trial, in grid order: trial, point, seed, the point's fields (by
  their dotted names), final_eval_return and best_eval_return (the periodic evaluation's
  last and best mean return, from metrics.json), then for td3 (the final model) and every
  baseline and planner `<policy>_return` and `<policy>_eliminated` (means over the
  evaluation episodes), then metrics.json's figures (timesteps, resumed_from,
  engagements, estimated_share, and the timings wall_seconds, steps_per_second,
  update_seconds, outside_update_share), then train_seconds and evaluate_seconds (the
  trial's whole training call and its evaluation). Only the timings (TIMING_COLUMNS), and
  resumed_from after a stop, differ between runs of the same trial: the training is seeded,
  a resumed one goes on exactly, and the evaluation episodes are seeded too;
- summary.csv: one row per point: the point's fields, seeds, then for td3's return and
  eliminated and for the final evaluation's return `<m>_mean` and `<m>_ci95` over seeds
  (farm.alloc.evaluate.mean_ci95; NaN half-width for one seed), then every baseline's and
  planner's `<policy>_return` and `<policy>_eliminated` (mean over the point's trials: the
  same episodes, so the same figures for every seed);
- claims.csv (one row per claim: claim, verdict over seeds, measured, rule) and claims_seeds.csv
  (each seed's measures of (a) and (b)), when the grid has a C_capture 0 and 1.5 pair;
- learning_curves.png: each point's periodic evaluation return over its finished seeds, the
  mean with a band (95% CI over seeds; min-max of 2 seeds);
- tune/: Ray Tune's experiment state.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import os
import threading
import time
import typing
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from farm.config import ConfigError, Strict, first_line, load_yaml_model, refuse_unknown_keys
from farm.errors import ClusterError, SwarmFarmError

__all__ = ["ExperimentConfig", "load_experiment_config", "Trial", "Plan", "plan", "trial_cpus", "run_experiment",
           "trials_table", "summary_table", "summary_view", "format_summary", "field_problem", "ExperimentError", "RESERVED_FIELDS", "TIMING_COLUMNS"]

RESERVED_FIELDS = ("name", "seed", "threads", "service")  # the experiment sets these for every trial
TIMING_COLUMNS = ("wall_seconds", "steps_per_second", "update_seconds", "outside_update_share", "train_seconds",
                  "evaluate_seconds")
METRICS_COLUMNS = ("timesteps", "resumed_from", "engagements", "estimated_share", *TIMING_COLUMNS[:4])
RESULT = "result.json"
MANIFEST = "experiment.json"
TUNE_DIR = "tune"
RESERVED_CPUS = 1.0  # left to the service's game tasks, whatever the trials hold
MAX_FAILURES = 2


class ExperimentError(SwarmFarmError):
    """A trial that failed (its error's first line, naming the trial)."""


# ----------------------------------------------------------------------------- config
class ExperimentConfig(Strict):
    """A `farm experiments` config (see the module doc); ConfigError or ValidationError, one
    line naming the field, for bad input."""

    name: str = Field(min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.-]+$")
    base: str | None = None
    scenario: str | None = None
    overrides: dict[str, Any] = {}
    grid: dict[str, list[Any]] = {}
    seeds: list[int]
    episodes: int = Field(10, ge=1, le=100_000)
    eval_seed: int = Field(1000, ge=0)
    store: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data):
        return refuse_unknown_keys(cls, data, "an experiments")

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v):
        if not v:
            raise ValueError("must name at least one seed")
        for s in v:
            if s < 0:
                raise ValueError(f"must be whole numbers >= 0, got {s}")
        if len(set(v)) != len(v):
            raise ValueError(f"a seed is named twice: {v}")
        return v

    @field_validator("overrides", "grid")
    @classmethod
    def _fields(cls, v, info):
        for path, values in v.items():
            problem = field_problem(path)
            if problem:
                raise ValueError(f"{path}: {problem}")
            if info.field_name == "grid":
                if not isinstance(values, list) or not values:
                    raise ValueError(f"{path}: must be a non-empty list of values, got {values!r}")
        return v

    @model_validator(mode="after")
    def _one_base(self):
        named = "scenario" in self.grid or "scenario" in self.overrides
        if self.base is not None and self.scenario is not None:
            raise ValueError("base: give one of `base` (a training config) or `scenario` (a suite scenario), not both")
        if self.base is None and self.scenario is None and not named:
            raise ValueError("base: give `base` (a training config), `scenario` (a suite scenario) or a grid over "
                             "`scenario`")
        if self.scenario is not None:
            from farm.alloc.scenarios import SCENARIOS

            if self.scenario not in SCENARIOS:
                raise ValueError(f"scenario: unknown scenario {self.scenario!r} (choose from {', '.join(SCENARIOS)})")
        both = set(self.overrides) & set(self.grid)
        if both:
            raise ValueError(f"grid: {sorted(both)[0]} is in `overrides` too; give it in one of them")
        return self


def field_problem(path: str) -> str | None:
    """Why a dotted field cannot be set by an experiment (None: it can): it must name a field
    of farm.alloc.train.TrainConfig through its sections, and not one of RESERVED_FIELDS."""
    from farm.alloc.train import TrainConfig

    parts = path.split(".")
    if not all(parts):
        return "not a dotted field name"
    if parts[0] in RESERVED_FIELDS:
        why = {"seed": "seeds come from `seeds`", "name": "trials are named after the experiment",
               "threads": "every trial trains on one torch thread",
               "service": "every trial uses the experiment's capture-time service (`store`)"}[parts[0]]
        return f"set by the experiment ({why})"
    model: Any = TrainConfig
    for depth, part in enumerate(parts):
        if model is dict or typing.get_origin(model) is dict:  # a free mapping (td3.policy_kwargs): checked later
            return None
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            return f"{'.'.join(parts[:depth])} has no fields"
        fields = model.model_fields
        if part not in fields:
            where = ".".join(parts[:depth]) or "a training config"
            return f"not a field of {where} (choose from {', '.join(f for f in fields if depth or f not in RESERVED_FIELDS)})"
        model = fields[part].annotation
    return None


def load_experiment_config(path) -> ExperimentConfig:
    """Read and validate an experiments YAML; ConfigError of one line naming the file and the field."""
    return load_yaml_model(path, ExperimentConfig, "experiments")


# ----------------------------------------------------------------------------- the plan
class Trial(BaseModel):
    """One (point, seed): key (the trial's folder name, p<point>_s<seed>), point (its index),
    seed, values (the point's grid values by dotted field) and config (the full TrainConfig
    as plain values)."""

    key: str
    point: int
    seed: int
    values: dict[str, Any]
    config: dict[str, Any]


class Plan(BaseModel):
    """An experiment resolved: its trials in grid order (points, then seeds), the grid's
    fields, the store (absolute) and the digest of everything that decides the results."""

    name: str
    fields: list[str]
    trials: list[Trial]
    store: str
    episodes: int
    eval_seed: int
    digest: str


def _set(raw: dict, path: str, value) -> None:
    node = raw
    parts = path.split(".")
    for part in parts[:-1]:
        child = node.get(part)
        if not isinstance(child, dict):
            child = {} if child is None else (child.model_dump() if isinstance(child, BaseModel) else child)
            if not isinstance(child, dict):
                child = {}
            node[part] = child
        node = child
    node[parts[-1]] = value


def _base_raw(config: ExperimentConfig, source: str) -> dict:
    """The base training config as plain values (validated once as a whole, its own errors
    naming the base file)."""
    from farm.alloc.train import load_train_config

    if config.scenario is not None:
        return {"scenario": config.scenario}
    if config.base is None:  # the grid or the overrides name the scenario
        return {}
    path = Path(config.base)
    load_train_config(path)  # one line naming the base file and its field
    raw = yaml.safe_load(path.read_text())
    return {k: v for k, v in raw.items() if k not in RESERVED_FIELDS or k == "service"}


def plan(config: ExperimentConfig, source: str = "experiments") -> Plan:
    """Resolve an experiment config into its trials (see Plan); ConfigError, one line naming
    `source` (the config file), the point and the field, for a point a training config refuses."""
    from farm.alloc.train import TrainConfig
    from farm.service.store import default_store_path

    base = _base_raw(config, source)
    service = dict(base.pop("service", None) or {})
    store = str(Path(config.store or default_store_path()).resolve())
    fields = list(config.grid)
    points = list(itertools.product(*(config.grid[f] for f in fields))) if fields else [()]
    trials = []
    for p, values in enumerate(points):
        for seed in config.seeds:
            raw = copy.deepcopy(base)
            for path, value in config.overrides.items():
                _set(raw, path, copy.deepcopy(value))
            for path, value in zip(fields, values):
                _set(raw, path, copy.deepcopy(value))
            key = f"p{p}_s{seed}"
            raw.update(name=f"{config.name}-{key}", seed=seed, threads=1,
                       service={"mode": "ray", "store": store, "address": None,
                                "warm_lattice": service.get("warm_lattice", True),
                                "estimates": service.get("estimates", False)})
            try:
                train = TrainConfig(**raw)
            except ValidationError as e:
                shown = ", ".join(f"{f}={v!r}" for f, v in zip(fields, values))
                raise ConfigError(f"{source}: {first_line(e)} (point {p}{': ' + shown if shown else ''})") from None
            trials.append(Trial(key=key, point=p, seed=seed, values=dict(zip(fields, values)),
                                config=json.loads(train.model_dump_json())))
    decided = {"name": config.name, "trials": [t.model_dump() for t in trials], "episodes": config.episodes,
               "eval_seed": config.eval_seed}
    for t in decided["trials"]:  # the store's place does not change a result
        t["config"]["service"] = {k: v for k, v in t["config"]["service"].items() if k != "store"}
    digest = hashlib.sha256(json.dumps(decided, sort_keys=True).encode()).hexdigest()[:16]
    return Plan(name=config.name, fields=fields, trials=trials, store=store, episodes=config.episodes,
                eval_seed=config.eval_seed, digest=digest)


def trial_cpus(cluster_cpus: float, workers: int) -> float:
    """The CPUs one trial asks for: min(1, (cluster_cpus - 1) / workers), rounded down to
    Ray's 1e-4, so that `workers` trials at once leave at least one CPU to the service's game
    tasks (see the module doc). ClusterError for a cluster of fewer than 2 CPUs."""
    if cluster_cpus < 1 + RESERVED_CPUS:
        raise ClusterError(f"workers: an experiment needs a Ray of at least 2 CPUs (one kept for the capture-time "
                           f"service's games), this one has {cluster_cpus:g}")
    share = min(1.0, (cluster_cpus - RESERVED_CPUS) / workers)
    return math.floor(share * 10_000) / 10_000


# ----------------------------------------------------------------------------- one trial
def _write_json(path: Path, doc: dict) -> None:
    from farm.output import atomic_write_bytes

    atomic_write_bytes(path, (json.dumps(doc, indent=2, default=float) + "\n").encode())


def _evaluate(config, run_dir: Path, episodes: int, seed: int) -> pd.DataFrame:
    """The final model, the baselines and the planners on episodes seed .. seed+episodes-1
    (one client on the shared service); writes eval_table.csv, eval_episodes.csv and
    eval_steps.csv into run_dir (farm eval's files, which farm claims reads); returns the table."""
    from farm.alloc.evaluate import baselines, evaluate_policies, load_policy, planners, steps_table
    from farm.output import write_table
    from farm.service.lookup import open_client

    with open_client(config.env.service_settings(), mode="ray", store=config.service.store) as client:
        policies = {"td3": load_policy(run_dir), **baselines(config.env.grid_size), **planners(config.env, client)}
        table, per, steps = evaluate_policies(config.env, policies, client, episodes, seed)
    write_table(table, run_dir / "eval_table", "csv")
    write_table(per, run_dir / "eval_episodes", "csv")
    write_table(steps_table(steps), run_dir / "eval_steps", "csv")
    return table


def _run_trial(params: dict) -> None:
    """The Tune trainable: train one trial (or resume it), evaluate it, write its result.json
    and report it (see the module doc). params: {"spec": {"trial": Trial as plain values,
    "dir": the trial's folder, "episodes", "eval_seed"}}."""
    from ray import tune

    from farm.alloc.train import TrainConfig, train
    from farm.experiments_tune import TuneReport

    spec = params["spec"]
    trial = Trial(**spec["trial"])
    folder = Path(spec["dir"])
    result_path = folder / RESULT
    if result_path.exists():  # finished before (e.g. the driver died after it): never trained again
        tune.report({**json.loads(result_path.read_text()), "phase": "done"})
        return
    config = TrainConfig(**trial.config)
    run_dir = folder / "run"
    resume = (run_dir / "config.yaml").exists()
    every = max(1, min(config.checkpoint_freq, config.td3.n_timesteps // 10 or 1))
    t0 = time.perf_counter()
    metrics = train(config, run_dir, resume=resume, show_progress=False, callbacks=[TuneReport(run_dir, every)])
    t1 = time.perf_counter()
    table = _evaluate(config, run_dir, spec["episodes"], spec["eval_seed"])
    t2 = time.perf_counter()
    result = {"trial": trial.key, "point": trial.point, "seed": trial.seed, **trial.values,
              "final_eval_return": metrics.get("final_eval_mean_return"),
              "best_eval_return": metrics.get("best_eval_mean_return")}
    for row in table.itertuples():
        result[f"{row.policy}_return"] = float(row.return_mean)
        result[f"{row.policy}_eliminated"] = float(row.eliminated_mean)
    result.update({name: metrics.get(name) for name in METRICS_COLUMNS})
    result.update(train_seconds=t1 - t0, evaluate_seconds=t2 - t1)
    _write_json(result_path, result)
    tune.report({**result, "phase": "done"})


def _trial_dirname(trial) -> str:
    """Tune's folder (and name) of a trial: the trial's key."""
    return trial.config["spec"]["trial"]["key"]


# ----------------------------------------------------------------------------- progress
# The running experiment's display: the Tune callback (farm.experiments_tune.Progress, pickled
# with Tune's state and unpickled on a restore) finds it here, so a restored experiment shows
# this run's progress.
_PROGRESS: dict = {}


class _Display:
    """Trials done, running and waiting, steps done and the ETA (tqdm's, over the steps this run
    trains), as a bar of steps on stderr. finished: the keys of trials finished before this run."""

    def __init__(self, plan: Plan, enabled: bool, finished: list[str]):
        from farm.progress import GameProgress

        self.total = {t.key: t.config["td3"]["n_timesteps"] for t in plan.trials}
        self.steps = {key: (self.total[key] if key in finished else 0) for key in self.total}
        self.done: set[str] = set(finished)
        self.running: set[str] = set()
        self.failed: set[str] = set()
        self.started_keys: set[str] = set()  # trials Tune started in this run
        self.lock = threading.Lock()
        self.bar = GameProgress(sum(self.total.values()), sum(self.steps.values()), enabled=enabled, desc="trials",
                                unit="step")
        self._describe()

    def _set_steps(self, key: str, steps: int) -> None:
        steps = min(int(steps), self.total[key])
        if steps > self.steps[key]:
            self.bar.update(steps - self.steps[key])
            self.steps[key] = steps

    def _describe(self) -> None:
        if self.bar.bar is not None:
            pending = len(self.total) - len(self.done) - len(self.running) - len(self.failed)
            failed = f", {len(self.failed)} failed" if self.failed else ""
            self.bar.bar.set_description_str(f"trials: {len(self.done)}/{len(self.total)} done, "
                                             f"{len(self.running)} running, {pending} waiting{failed}")

    def started(self, key: str) -> None:
        """A trial started (or restarted)."""
        with self.lock:
            self.running.add(key)
            self.started_keys.add(key)
            self._describe()

    def result(self, key: str, result: dict) -> None:
        """A trial reported."""
        with self.lock:
            if "timesteps" in result and result["timesteps"] is not None:
                self._set_steps(key, result["timesteps"])
            self.running.add(key)
            self._describe()

    def ended(self, key: str, ok: bool) -> None:
        """A trial finished (ok) or failed."""
        with self.lock:
            self.running.discard(key)
            if ok:
                self._set_steps(key, self.total[key])
                self.done.add(key)
            else:
                self.failed.add(key)
            self._describe()

    def close(self) -> None:
        """Close the bar."""
        self.bar.close()


# ----------------------------------------------------------------------------- the run
def _check_out(out: Path, plan: Plan) -> None:
    """ConfigError (one line naming out) when out holds another experiment, or files that are
    not an experiment's."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"out: {out} exists and is not a folder")
    manifest = out / MANIFEST
    if manifest.exists():
        try:
            doc = json.loads(manifest.read_text())
            digest, name = doc["digest"], doc["name"]
        except (ValueError, KeyError, TypeError):
            raise ConfigError(f"out: {manifest} is damaged; choose another folder") from None
        if digest != plan.digest:
            raise ConfigError(f"out: {out} holds another experiment ({name}, config digest {digest}, not "
                              f"{plan.digest}); choose another folder")
    elif out.exists() and any(out.iterdir()):
        raise ConfigError(f"out: {out} is not empty and holds no experiment ({MANIFEST}); choose another folder")


def _manifest_trials(plan: Plan) -> list[dict]:
    """experiment.json's list of trials: {key, point, seed, values} each, in grid order."""
    return [{"key": t.key, "point": t.point, "seed": t.seed, "values": t.values} for t in plan.trials]


def _write_manifest(config: ExperimentConfig, plan: Plan, out: Path) -> None:
    if (out / MANIFEST).exists():
        return
    out.mkdir(parents=True, exist_ok=True)
    _write_json(out / MANIFEST, {
        "name": plan.name, "digest": plan.digest, "config": config.model_dump(mode="json", exclude_unset=True),
        "store": plan.store, "fields": plan.fields,
        "trials": _manifest_trials(plan)})


def _warm(plan: Plan, actor, show_progress: bool) -> int:
    """Compute every lattice point's pairs on the service first (all points' at once); returns the cases."""
    from farm.alloc.config import AllocConfig
    from farm.alloc.suite import _lattice_by_settings
    from farm.progress import GameProgress
    from farm.service.lookup import CaptureTimeClient

    envs = {t.key: AllocConfig(**t.config["env"]) for t in plan.trials if t.config["service"]["warm_lattice"]}
    groups = _lattice_by_settings(envs)
    total = sum(len(pairs) for _, pairs in groups)
    if not total:
        return 0
    bar = GameProgress(total, enabled=show_progress, desc="capture-time lattice", unit="case")
    try:
        for env, pairs in groups:
            CaptureTimeClient(env.service_settings(), service=actor).warm(pairs, progress=bar.update)
    finally:
        bar.close()
    return total


def run_experiment(config: ExperimentConfig, out, *, source: str = "experiments", address: str | None = None,
                   workers: int | None = None, show_progress: bool = True,
                   warm: bool = True) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Run or resume an experiment into the folder out (see the module doc); returns
    (trials.csv's table, summary.csv's table, info).

    address: a Ray cluster to join (default $RAY_ADDRESS, else a local Ray of max(2,
    workers) CPUs); workers: trials at once (default: the cluster's CPUs); warm: False
    skips the lattice warm-up, in the driver and in every trial (the tests use it to make
    trials miss on a cold store). info: trials run this time and before, the CPUs per
    trial, the warm-up's cases and seconds, the wall seconds, the claims' files and the
    learning curves' figure written (claims: a list of paths, learning_curves: a path or None).
    ConfigError (one line) for bad input before Ray starts; ExperimentError naming the first
    trial that failed (after the tables of the others are written).
    """
    from farm.runtime import connected
    from farm.service.lookup import open_client

    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ConfigError(f"workers: must be a whole number >= 1, got {workers!r}")
    the_plan = plan(config, source)
    if not warm:
        for t in the_plan.trials:
            t.config["service"]["warm_lattice"] = False
    out = Path(out).resolve()
    _check_out(out, the_plan)
    _write_manifest(config, the_plan, out)
    before = [t.key for t in the_plan.trials if (out / "trials" / t.key / RESULT).exists()]
    joined = bool(address or os.environ.get("RAY_ADDRESS"))
    starts_ray = not joined and not connected()
    first = the_plan.trials[0].config["env"]
    from farm.alloc.config import AllocConfig

    info: dict = {"trials": len(the_plan.trials), "finished_before": len(before), "warmed_cases": 0}
    t0 = time.perf_counter()
    with open_client(AllocConfig(**first).service_settings(), mode="ray", store=the_plan.store, address=address,
                     num_cpus=max(2, workers or 2) if starts_ray else None) as client:
        import ray

        if warm and len(before) < len(the_plan.trials):  # a trial left to run
            info["warmed_cases"] = _warm(the_plan, client.backend.actor, show_progress)
        info["warm_seconds"] = time.perf_counter() - t0
        cpus = float(ray.cluster_resources().get("CPU", 0))
        k = min(workers or max(1, int(cpus)), len(the_plan.trials))
        share = trial_cpus(cpus, k)
        info.update(workers=k, trial_cpus=share, cluster_cpus=cpus)
        display = _Display(the_plan, show_progress, before)
        _PROGRESS["display"] = display
        try:
            results = _fit(the_plan, out, k, share)
        finally:
            _PROGRESS.pop("display", None)
            display.close()
        info["started"] = len(display.started_keys)
    info["seconds"] = time.perf_counter() - t0
    trials = trials_table(the_plan, out)
    summary = summary_table(the_plan.fields, trials)
    from farm.output import write_table

    write_table(trials, out / "trials", "csv")
    write_table(summary, out / "summary", "csv")
    info.update(_write_claims_and_curves(out))
    errors = [(r.error, r.path) for r in results if r.error is not None]
    info["tune_finished"] = sum(1 for r in results if r.error is None and (r.metrics or {}).get("phase") == "done")
    if errors:
        error, path = errors[0]
        problem = (str(error).strip().splitlines() or [type(error).__name__])[-1]
        raise ExperimentError(f"trial {Path(path).name} failed ({len(errors)} of {len(results)} failed): {problem}")
    if len(trials) < len(the_plan.trials):  # Tune was stopped (Ctrl+C): its state is saved
        raise ExperimentError(f"{len(the_plan.trials) - len(trials)} of {len(the_plan.trials)} trials unfinished "
                              f"(interrupted); run the same command again to go on")
    return trials, summary, info


def _write_claims_and_curves(out: Path) -> dict:
    """The paper's claims over the seeds (claims.csv, claims_seeds.csv; when the experiment has
    a C_capture 0 and 1.5 pair: farm.alloc.claims.claims_over_seeds) and the learning curves
    over seeds (learning_curves.png); returns {claims: the files written, learning_curves: the
    figure's path or None}."""
    from farm.alloc.claims import claims_over_seeds, write_claims_over_seeds
    from farm.experiments_results import write_learning_curves

    found = claims_over_seeds(out)
    return {"claims": write_claims_over_seeds(out, found) if found.pair is not None and found.rows else [],
            "learning_curves": write_learning_curves(out)}


def _fit(plan: Plan, out: Path, workers: int, share: float):
    """Run (or restore and go on with) the Tune experiment; returns its ResultGrid."""
    from ray import tune

    from farm.experiments_tune import Progress

    trainable = tune.with_resources(_run_trial, {"cpu": share})
    path = out / TUNE_DIR
    if tune.Tuner.can_restore(str(path)):
        tuner = tune.Tuner.restore(str(path), trainable=trainable, resume_unfinished=True, resume_errored=True)
    else:
        specs = [{"trial": t.model_dump(), "dir": str(out / "trials" / t.key), "episodes": plan.episodes,
                  "eval_seed": plan.eval_seed} for t in plan.trials]
        tuner = tune.Tuner(
            trainable,
            param_space={"spec": tune.grid_search(specs)},
            tune_config=tune.TuneConfig(max_concurrent_trials=workers, reuse_actors=True, trial_dirname_creator=_trial_dirname,
                                        trial_name_creator=_trial_dirname),
            run_config=tune.RunConfig(name=TUNE_DIR, storage_path=str(out),
                                      failure_config=tune.FailureConfig(max_failures=MAX_FAILURES),
                                      checkpoint_config=tune.CheckpointConfig(num_to_keep=2),
                                      verbose=0, callbacks=[Progress()]),
        )
    with _quiet_tune():
        return tuner.fit()


# Ray Tune's own output, off while an experiment runs (its progress is farm's bar): the new
# output engine prints a configuration box whatever the verbosity, the legacy one is silent at
# verbose=0; the warning that saving the experiment's state took long is meant for remote storage;
# the warning that TensorboardX is missing is about Tune's own result logger (each trial's
# TensorBoard logs are SB3's, in its run folder).
_TUNE_QUIET = {"RAY_AIR_NEW_OUTPUT": "0", "TUNE_WARN_EXCESSIVE_EXPERIMENT_CHECKPOINT_SYNC_THRESHOLD_S": "0"}
_TUNE_QUIET_LOGGER = "ray.tune.utils.callback"


@contextmanager
def _quiet_tune():
    """Set _TUNE_QUIET's variables that are not set, and _TUNE_QUIET_LOGGER's level to errors
    only, for the block."""
    import logging

    added = [name for name in _TUNE_QUIET if name not in os.environ]
    os.environ.update({name: _TUNE_QUIET[name] for name in added})
    quiet = logging.getLogger(_TUNE_QUIET_LOGGER)
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        yield
    finally:
        quiet.setLevel(level)
        for name in added:
            os.environ.pop(name, None)


# ----------------------------------------------------------------------------- the tables
def trials_table(plan: Plan, out: Path) -> pd.DataFrame:
    """trials.csv (see the module doc) from the trials' result.json files, in grid order; a
    trial without one (not finished) is left out."""
    from farm.experiments_results import finished_trials

    return pd.DataFrame([t["result"] for t in finished_trials(out, {"trials": _manifest_trials(plan)})])


def summary_table(fields: list[str], trials: pd.DataFrame) -> pd.DataFrame:
    """summary.csv (see the module doc): one row per point with finished trials; fields: the
    grid's dotted fields (Plan.fields), trials: trials.csv's table."""
    from farm.alloc.evaluate import mean_ci95

    if trials.empty:
        return pd.DataFrame()
    others = [c[: -len("_return")] for c in trials.columns
              if c.endswith("_return") and c not in ("td3_return", "final_eval_return", "best_eval_return")]
    rows = []
    for point, g in trials.groupby("point", sort=True):
        row = {"point": int(point), **{f: g[f].iloc[0] for f in fields}, "seeds": len(g)}
        for name, col in (("return", "td3_return"), ("eliminated", "td3_eliminated"),
                          ("final_eval_return", "final_eval_return")):
            x = g[col].to_numpy(dtype=float)
            x = x[np.isfinite(x)]
            row[f"{name}_mean"], row[f"{name}_ci95"] = mean_ci95(x) if len(x) else (math.nan, math.nan)
        for name in others:
            row[f"{name}_return"] = float(g[f"{name}_return"].mean())
            row[f"{name}_eliminated"] = float(g[f"{name}_eliminated"].mean())
        rows.append(row)
    return pd.DataFrame(rows)


def summary_view(summary: pd.DataFrame) -> pd.DataFrame:
    """summary.csv as shown (format_summary, farm report): point, the point's fields, seeds,
    td3's return and eliminated as `mean ± CI` strings, and the baseline or planner eliminating
    the most (`name value`); an empty frame for an empty summary."""

    def pm(m, h):
        return f"{m:.3f} ± {h:.3f}" if math.isfinite(h) else f"{m:.3f}"

    if summary.empty:
        return pd.DataFrame()
    fields = list(summary.columns[1: list(summary.columns).index("seeds") + 1])
    view = summary[["point", *fields]].copy()
    view["td3 return"] = [pm(m, h) for m, h in zip(summary["return_mean"], summary["return_ci95"])]
    view["td3 eliminated"] = [pm(m, h) for m, h in zip(summary["eliminated_mean"], summary["eliminated_ci95"])]
    others = [c[: -len("_eliminated")] for c in summary.columns if c.endswith("_eliminated")]
    if others:
        best = [max(others, key=lambda n: r[f"{n}_eliminated"]) for _, r in summary.iterrows()]
        view["best other (eliminated)"] = [f"{n} {r[f'{n}_eliminated']:.3f}" for n, (_, r) in zip(best, summary.iterrows())]
    return view


def format_summary(summary: pd.DataFrame) -> str:
    """summary.csv as a text table (summary_view)."""
    if summary.empty:
        return "(no finished trials)"
    return summary_view(summary).to_string(index=False)
