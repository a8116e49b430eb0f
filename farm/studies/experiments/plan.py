"""An experiment resolved into its trials: Trial, Plan (with the digest of everything that
decides the results), plan() and the CPUs one trial asks for (trial_cpus; docs/experiments.md
says why a share of the CPUs is left to the service's games)."""

from __future__ import annotations

import copy
import hashlib
import json
import math
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from farm.core.config import ConfigError, first_line, read_yaml
from farm.core.errors import ClusterError
from farm.studies.experiments.config import RESERVED_FIELDS, UNSET, ExperimentConfig

__all__ = ["Trial", "Plan", "plan", "trial_cpus", "RESERVED_CPUS"]

RESERVED_CPUS = 1.0  # left to the service's game tasks, whatever the trials hold


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


def _added_defaults() -> dict:
    """The training config's fields older trial configs lack (the learners, tracking), at their defaults, as
    plain values: a trial's config holding one at its default decides what it did before."""
    from farm.alloc.training import TrainConfig

    defaults = json.loads(TrainConfig(name="x").model_dump_json())
    return {name: defaults[name] for name in ("algo", "ppo", "sac", "n_envs", "pretrain", "keep", "tracking")}


def _base_raw(config: ExperimentConfig, source: str) -> dict:
    """The base training config as plain values (validated once as a whole, its own errors
    naming the base file)."""
    from farm.alloc.training import load_train_config

    if config.scenario is not None:
        return {"scenario": config.scenario}
    if config.base is None:  # the grid or the overrides name the scenario
        return {}
    path = Path(config.base)
    load_train_config(path)  # one line naming the base file and its field
    raw = read_yaml(path)
    return {k: v for k, v in raw.items() if k not in RESERVED_FIELDS or k == "service"}


def plan(config: ExperimentConfig, source: str = "experiments") -> Plan:
    """Resolve an experiment config into its trials (see Plan); ConfigError, one line naming
    `source` (the config file), the point and the field, for a point a training config refuses."""
    from farm.alloc.training import TrainConfig
    from farm.alloc.training.config import check_trainable
    from farm.service.store import default_store_path

    base = _base_raw(config, source)
    service = dict(base.pop("service", None) or {})
    store = str(Path(config.store or default_store_path()).resolve())
    fields, points = config.point_list()
    trials = []
    for p, values in enumerate(points):
        for seed in config.seeds:
            raw = copy.deepcopy(base)
            for path, value in config.overrides.items():
                _set(raw, path, copy.deepcopy(value))
            for path, value in zip(fields, values):
                if value is not UNSET:
                    _set(raw, path, copy.deepcopy(value))
            key = f"p{p}_s{seed}"
            raw.update(name=f"{config.name}-{key}", seed=seed, threads=1,
                       service={"mode": "ray", "store": store, "address": None,
                                "warm_lattice": service.get("warm_lattice", True),
                                "estimates": service.get("estimates", False)})
            try:
                train = TrainConfig(**raw)
                check_trainable(train)
            except (ValidationError, ConfigError) as e:
                shown = ", ".join(f"{f}={v!r}" for f, v in zip(fields, values))
                raise ConfigError(f"{source}: {first_line(e)} (point {p}{': ' + shown if shown else ''})") from None
            trials.append(Trial(key=key, point=p, seed=seed,
                                values={f: v for f, v in zip(fields, values) if v is not UNSET},
                                config=json.loads(train.model_dump_json())))
    decided = {"name": config.name, "trials": [t.model_dump() for t in trials], "episodes": config.episodes,
               "eval_seed": config.eval_seed}
    for t in decided["trials"]:  # the store's place does not change a result
        t["config"]["service"] = {k: v for k, v in t["config"]["service"].items() if k != "store"}
        for name, default in _added_defaults().items():  # at its default: as an older config without it
            if t["config"].get(name) == default:
                del t["config"][name]
    digest = hashlib.sha256(json.dumps(decided, sort_keys=True).encode()).hexdigest()[:16]
    return Plan(name=config.name, fields=fields, trials=trials, store=store, episodes=config.episodes,
                eval_seed=config.eval_seed, digest=digest)


def trial_cpus(cluster_cpus: float, workers: int) -> float:
    """The CPUs one trial asks for: min(1, (cluster_cpus - 1) / workers), rounded down to
    Ray's 1e-4, so that `workers` trials at once leave at least one CPU to the service's game
    tasks (see the module doc). ClusterError for a cluster of fewer than 2 CPUs."""
    if cluster_cpus < 1 + RESERVED_CPUS:
        raise ClusterError(f"workers: an experiment needs a Ray of at least 2 CPUs (one kept for the capture-time "
                           f"service's games), this one has {cluster_cpus:g}", field="workers")
    share = min(1.0, (cluster_cpus - RESERVED_CPUS) / workers)
    return math.floor(share * 10_000) / 10_000
