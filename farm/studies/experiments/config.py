"""A `farm experiments` config (ExperimentConfig, load_experiment_config) and the dotted fields a
grid may set (field_problem); docs/experiments.md shows one."""

from __future__ import annotations

import itertools
import types
import typing
from typing import Any

from pydantic import BaseModel, Field, field_validator, model_validator

from farm.core.config import StrictFile, load_yaml_model
from farm.core.tracking import TrackingParams

__all__ = ["ExperimentConfig", "load_experiment_config", "field_problem", "RESERVED_FIELDS", "UNSET"]

RESERVED_FIELDS = ("name", "seed", "threads", "service", "tracking")  # the experiment sets these for every trial


class ExperimentConfig(StrictFile):
    """A `farm experiments` config (see the module doc); ConfigError or ValidationError, one
    line naming the field, for bad input."""

    KIND = "an experiments"

    # the experiment's name: its trials are named NAME-<trial>; MLflow's default experiment
    name: str = Field(min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.-]+$")
    base: str | None = None  # a training config's path, the trials' base (or give scenario)
    scenario: str | None = None  # a suite scenario's name, with TrainConfig's defaults (or give base)
    overrides: dict[str, Any] = {}  # dotted TrainConfig field -> value, set in every trial
    grid: dict[str, list[Any]] = {}  # dotted TrainConfig field -> values: the points, a cartesian product
    points: list[dict[str, Any]] = []  # or the points themselves: each a mapping of dotted TrainConfig fields to values
    seeds: list[int]  # each (point, seed) is one trial, its TrainConfig.seed
    # evaluation episodes: each trial's model, the baselines and the planners
    episodes: int = Field(10, ge=1, le=100_000)
    eval_seed: int = Field(1000, ge=0)  # evaluation episodes are seeded eval_seed .. eval_seed + episodes - 1
    # the capture-time store every trial shares; None: default_store_path()
    store: str | None = Field(None, min_length=1)
    tracking: TrackingParams = TrackingParams()  # MLflow: a run per trial (farm.core.tracking); not in the digest

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

    @field_validator("points")
    @classmethod
    def _points(cls, v):
        for i, point in enumerate(v):
            if not isinstance(point, dict) or not point:
                raise ValueError(f"point {i}: must be a mapping of dotted fields to values, got {point!r}")
            for path in point:
                problem = field_problem(path)
                if problem:
                    raise ValueError(f"point {i}: {path}: {problem}")
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
        named = "scenario" in self.grid or "scenario" in self.overrides or \
            (self.points and all("scenario" in point for point in self.points))
        if self.base is not None and self.scenario is not None:
            raise ValueError("base: give one of `base` (a training config) or `scenario` (a suite scenario), not both")
        if self.base is None and self.scenario is None and not named:
            raise ValueError("base: give `base` (a training config), `scenario` (a suite scenario) or a grid over "
                             "`scenario`")
        if self.scenario is not None:
            from farm.alloc.game.scenarios import SCENARIOS

            if self.scenario not in SCENARIOS:
                raise ValueError(f"scenario: unknown scenario {self.scenario!r} (choose from {', '.join(SCENARIOS)})")
        both = set(self.overrides) & (set(self.grid) | {f for point in self.points for f in point})
        if both:
            raise ValueError(f"grid: {sorted(both)[0]} is in `overrides` too; give it in one of them")
        if self.grid and self.points:
            raise ValueError("points: give the points as a `grid` (a cartesian product) or as `points`, not both")
        return self

    def point_list(self) -> tuple[list[str], list[tuple]]:
        """(the fields the points set, in order of first appearance; each point's values in that
        order, None for a field a point leaves out): the grid's cartesian product, or `points`."""
        if not self.points:
            fields = list(self.grid)
            return fields, list(itertools.product(*(self.grid[f] for f in fields))) if fields else [()]
        fields = list(dict.fromkeys(f for point in self.points for f in point))
        return fields, [tuple(point.get(f, UNSET) for f in fields) for point in self.points]


class _Unset:
    """A field a point leaves at the base's value."""

    def __repr__(self) -> str:
        return "unset"


UNSET = _Unset()


def field_problem(path: str) -> str | None:
    """Why a dotted field cannot be set by an experiment (None: it can): it must name a field
    of farm.alloc.training.TrainConfig through its sections, and not one of RESERVED_FIELDS."""
    from farm.alloc.training import TrainConfig

    parts = path.split(".")
    if not all(parts):
        return "not a dotted field name"
    if parts[0] in RESERVED_FIELDS:
        why = {"seed": "seeds come from `seeds`", "name": "trials are named after the experiment",
               "threads": "every trial trains on one torch thread",
               "service": "every trial uses the experiment's capture-time service (`store`)",
               "tracking": "the experiment's own `tracking` block tracks every trial"}[parts[0]]
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
            choices = ", ".join(f for f in fields if depth or f not in RESERVED_FIELDS)
            return f"not a field of {where} (choose from {choices})"
        model = fields[part].annotation
        if typing.get_origin(model) in (typing.Union, types.UnionType):  # an optional section (pretrain)
            models = [a for a in typing.get_args(model) if isinstance(a, type) and issubclass(a, BaseModel)]
            model = models[0] if len(models) == 1 else model
    return None


def load_experiment_config(path) -> ExperimentConfig:
    """Read and validate an experiments YAML; ConfigError of one line naming the file and the field."""
    return load_yaml_model(path, ExperimentConfig, "experiments")
