"""Typed sweep configs (YAML): unknown keys and bad values are rejected with one
line naming the field. Every default lives here or in workers.Case.

    name: team-sizes
    seed: 0
    games_per_point: 50
    shard_games: null          # games per Ray task; null: chosen from the team size
    base:                      # the game every point starts from (workers.Case fields)
      n_pursuers: 3
      n_evaders: 1
      pursuer_policy: area_min
      evader_policy: centroid
      exit_point: null         # [x, y]: evaders escape there (model v2); null: no escapes
      pursuer_speed: 1.0       # team speeds (v_max of each side)
      evader_speed: 1.0
    vary:                      # each block present is one axis of a cartesian product
      grid: {n_pursuers: [1, 2, 3], evader_policy: [centroid, constant_area]}
      zip: {capture_radius: [0.2, 0.3], dt: [0.01, 0.005]}     # lists in step
      random: {n: 8, ranges: {capture_radius: [0.1, 0.5]}}     # n uniform draws
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from workers import ENGINE_VERSION, Case, InitialLaw, InputError
from workers.engine import estimated_game_seconds

__all__ = ["SweepConfig", "Point", "load_sweep_config", "ConfigError", "VARIABLE_FIELDS"]

class ConfigError(ValueError):
    """A bad config: one line naming the file, the field and the problem."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


_CASE = Case(3, 1)  # the defaults of every game field are workers.Case's


class LawModel(_Strict):
    kind: Literal["boxes", "uniform"] = _CASE.law.kind
    pursuer_box: tuple[float, float, float, float] = _CASE.law.pursuer_box
    evader_box: tuple[float, float, float, float] = _CASE.law.evader_box


class GameModel(_Strict):
    """The base game: the fields of workers.Case, with its defaults."""

    n_pursuers: int = Field(_CASE.n_pursuers, ge=1, le=10_000)
    n_evaders: int = Field(_CASE.n_evaders, ge=1, le=10_000)
    pursuer_policy: str = _CASE.pursuer_policy
    evader_policy: str = _CASE.evader_policy
    capture_radius: float = Field(_CASE.capture_radius, gt=0, allow_inf_nan=False)
    dt: float = Field(_CASE.dt, gt=0, allow_inf_nan=False)
    t_max: float = Field(_CASE.t_max, gt=0, allow_inf_nan=False)
    tau: float = Field(_CASE.tau, gt=0, allow_inf_nan=False)
    target: tuple[float, float] = _CASE.target
    arena: list[tuple[float, float]] | None = None
    law: LawModel = LawModel()
    exit_point: tuple[float, float] | None = _CASE.exit_point
    pursuer_speed: float = Field(_CASE.pursuer_speed, gt=0, allow_inf_nan=False)
    evader_speed: float = Field(_CASE.evader_speed, gt=0, allow_inf_nan=False)

    def to_case(self, validate: bool = True) -> Case:
        """The workers.Case of this game, validated (unknown policies, bad arena...) unless
        validate=False."""
        law = InitialLaw(kind=self.law.kind, pursuer_box=tuple(self.law.pursuer_box),
                         evader_box=tuple(self.law.evader_box))
        arena = None if self.arena is None else tuple(tuple(float(c) for c in v) for v in self.arena)
        plain = self.model_dump(include=set(VARIABLE_FIELDS))  # Case normalises tuples and numbers
        case = Case(**plain, arena=arena, law=law)
        return case.validate() if validate else case


# What a sweep may vary: every game field but the arena and the law; the numeric ones may be drawn at random.
VARIABLE_FIELDS = tuple(name for name in GameModel.model_fields if name not in ("arena", "law"))
_INT_FIELDS = {name for name in VARIABLE_FIELDS if GameModel.model_fields[name].annotation is int}
_FLOAT_FIELDS = {name for name in VARIABLE_FIELDS if GameModel.model_fields[name].annotation is float}


class RandomModel(_Strict):
    n: int = Field(ge=1, le=100_000)
    ranges: dict[str, tuple[float, float]]

    @field_validator("ranges")
    @classmethod
    def _ranges(cls, v):
        for name, (lo, hi) in v.items():
            if name not in _INT_FIELDS | _FLOAT_FIELDS:
                raise ValueError(f"{name!r} cannot be drawn at random (numeric fields: "
                                 f"{', '.join(sorted(_INT_FIELDS | _FLOAT_FIELDS))})")
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
                raise ValueError(f"{name}: range must be [low, high] with low <= high")
        return v


class VaryModel(_Strict):
    grid: dict[str, list[Any]] | None = None
    zip: dict[str, list[Any]] | None = None
    random: RandomModel | None = None

    @field_validator("grid", "zip")
    @classmethod
    def _known_fields(cls, v):
        if v is None:
            return v
        for name, values in v.items():
            if name not in VARIABLE_FIELDS:
                raise ValueError(f"{name!r} cannot vary (choose from {', '.join(VARIABLE_FIELDS)})")
            if len(values) == 0:
                raise ValueError(f"{name}: needs at least one value")
        return v

    @model_validator(mode="after")
    def _zip_lengths(self):
        if self.zip:
            lengths = {len(v) for v in self.zip.values()}
            if len(lengths) > 1:
                raise ValueError(f"zip: lists must have the same length, got {sorted(lengths)}")
        names = [set(b) for b in (self.grid or {}, self.zip or {}, (self.random.ranges if self.random else {}))]
        for a, b in itertools.combinations(names, 2):
            if a & b:
                raise ValueError(f"{sorted(a & b)[0]}: varies in two blocks")
        return self


class SweepConfig(_Strict):
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = Field(0, ge=0)
    games_per_point: int = Field(50, ge=1, le=10_000_000)
    shard_games: int | None = Field(None, ge=1, le=100_000)
    base: GameModel = GameModel()
    vary: VaryModel = VaryModel()

    def points(self) -> list["Point"]:
        """The resolved points of the sweep, in a fixed order."""
        axes: list[list[dict]] = []
        v = self.vary
        if v.grid:
            names = list(v.grid)
            axes.append([dict(zip(names, combo)) for combo in itertools.product(*v.grid.values())])
        if v.zip:
            names = list(v.zip)
            axes.append([dict(zip(names, row)) for row in zip(*v.zip.values())])
        if v.random:
            rng = np.random.default_rng([self.seed, 0x5EED])
            draws = []
            for _ in range(v.random.n):
                d = {}
                for name, (lo, hi) in v.random.ranges.items():
                    d[name] = int(rng.integers(int(lo), int(hi) + 1)) if name in _INT_FIELDS else float(rng.uniform(lo, hi))
                draws.append(d)
            axes.append(draws)
        combos = [{}] if not axes else [dict(kv for part in parts for kv in part.items()) for parts in itertools.product(*axes)]
        out = []
        base = self.base.model_dump()
        for index, changes in enumerate(combos):
            fields = {**base, **changes}
            try:
                case = GameModel(**fields).to_case()  # re-validates values coming from `vary`
            except (InputError, ValidationError, TypeError, ValueError) as e:
                where = ", ".join(f"{k}={v!r}" for k, v in changes.items())
                prefix = f"vary: point {index} ({where})" if changes else "base"
                raise ConfigError(f"{prefix}: {_first_line(e)}") from None
            shard = self.shard_games or default_shard_games(case)
            out.append(Point(index, changes, case, self.games_per_point, shard))
        return out

    def sweep_id(self) -> str:
        """Hash of the resolved sweep: every point's case key, games, shards and seed."""
        blob = json.dumps(
            {"seed": self.seed, "points": [p.identity() for p in self.points()], "engine": ENGINE_VERSION},
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _first_line(e: Exception) -> str:
    if isinstance(e, ValidationError):
        err = e.errors()[0]
        loc = ".".join(str(x) for x in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        return f"{loc}: {msg}" if loc else msg
    return str(e).splitlines()[0]


SHARD_SECONDS = 0.5


def default_shard_games(case: Case) -> int:
    """Games per Ray task: about half a second of work on one core by the engine's cost
    model, so that the cost of a task beyond its games (Ray's dispatch and the shard's atomic
    Parquet write, 10-20 ms measured by benchmarks/farm.py) stays under 5%."""
    seconds = estimated_game_seconds(case.n_pursuers, case.n_evaders, case.pursuer_policy, case.evader_policy,
                                     case.t_max, case.dt, case.pursuer_speed, case.evader_speed)
    return int(min(100_000, max(1, round(SHARD_SECONDS / seconds))))


class Point:
    """One point of a sweep: its index, what it changes, its Case, and its shards."""

    def __init__(self, index: int, changes: dict, case: Case, games: int, shard_games: int):
        self.index, self.changes, self.case = index, changes, case
        self.games, self.shard_games = games, shard_games

    def shards(self) -> list[tuple[int, int, int]]:
        """(shard number, first game, end game) of every shard of the point."""
        return [(k, s, min(self.games, s + self.shard_games)) for k, s in enumerate(range(0, self.games, self.shard_games))]

    def identity(self) -> dict:
        return {"index": self.index, "case": self.case.key(), "games": self.games, "shard_games": self.shard_games}


def load_yaml_model(path: str | Path, model: type[BaseModel], what: str, check=None):
    """Read a YAML mapping into a typed model, then run check(config) (deeper validation)
    if given; any problem is a ConfigError of one line."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        raise ConfigError(f"{path}: not valid YAML{where}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: must be a mapping of {what} fields")
    try:
        config = model(**raw)
        if check is not None:
            check(config)
        return config
    except ValidationError as e:
        raise ConfigError(f"{path}: {_first_line(e)}") from None
    except (TypeError, InputError, ConfigError) as e:
        raise ConfigError(f"{path}: {e}") from None


def load_sweep_config(path: str | Path) -> SweepConfig:
    """Read and validate a sweep YAML; raises ConfigError with one line."""
    return load_yaml_model(path, SweepConfig, "sweep", check=SweepConfig.points)
