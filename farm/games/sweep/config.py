"""Typed sweep configs (YAML): unknown keys and bad values are rejected with one
line naming the field. A sweep names workers.Case's fields and takes its defaults.
SweepConfig's docstring is an example.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from typing import Any

import numpy as np
from pydantic import Field, field_validator, model_validator

from farm.core.config import NUMERIC_FIELDS, ConfigError, Strict, case_from, check_game_names, load_yaml_model
from farm.games.shards import MAX_SHARD_GAMES, games_per_shard, shard_ranges
from farm.games.sizes import ITEM_BYTES, JobSize, game_seconds
from workers import ENGINE_VERSION, GAME_FIELDS, SEEDING, Case, InputError

__all__ = ["SweepConfig", "Point", "load_sweep_config", "VARIABLE_FIELDS", "FULL_CHECK_POINTS"]

FULL_CHECK_POINTS = 20_000  # a sweep with more points has each axis value checked once when loaded

# What a sweep may vary: every game field but the arena and the initial-position law.
VARIABLE_FIELDS = tuple(name for name in GAME_FIELDS if name not in ("arena", "law"))


class RandomModel(Strict):
    """`vary.random`: n seeded draws, each field uniform in its [low, high] range (for an int
    field, the whole numbers in it: a range holding none is refused)."""

    n: int = Field(ge=1, le=100_000)  # how many random draws (points of this axis)
    ranges: dict[str, tuple[float, float]]  # numeric Case field -> [low, high], drawn uniformly

    @field_validator("ranges")
    @classmethod
    def _ranges(cls, v):
        for name, (lo, hi) in v.items():
            if name not in NUMERIC_FIELDS:
                raise ValueError(f"{name!r} cannot be drawn at random (numeric fields: "
                                 f"{', '.join(sorted(NUMERIC_FIELDS))})")
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
                raise ValueError(f"{name}: range must be [low, high] with low <= high")
            if NUMERIC_FIELDS[name] is int and math.ceil(lo) > math.floor(hi):
                raise ValueError(f"{name}: [{lo:g}, {hi:g}] holds no whole number, and {name} is one")
        return v


class VaryModel(Strict):
    """`vary`: what changes between points, `grid` (cartesian product), `zip` (lists in step) and
    `random`; their product."""

    grid: dict[str, list[Any]] | None = None  # Case field -> values: one axis per field (cartesian product)
    zip: dict[str, list[Any]] | None = None  # Case field -> values: lists of one length, taken in step
    random: RandomModel | None = None  # n seeded uniform draws of numeric fields (one axis)

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

    def names(self) -> list[str]:
        """The fields that vary, in the order the blocks name them."""
        return varied_names(self.model_dump())


def varied_names(vary: dict) -> list[str]:
    """The fields a sweep's `vary` mapping (as in sweep.json) varies, in the order its blocks name them."""
    out: list[str] = []
    random = vary.get("random") or {}
    for block in (vary.get("grid") or {}, vary.get("zip") or {}, random.get("ranges") or {}):
        out += [n for n in block if n not in out]
    return out


class SweepConfig(Strict):
    """A sweep config: name, seed, games per point, shard size, the base game and what varies.

    One reads, for example:

        name: team-sizes
        seed: 0
        games_per_point: 50
        shard_games: null          # games per Ray task; null: chosen from the team size
        base:                      # the game every point starts from: workers.Case fields
          n_pursuers: 3
          n_evaders: 1
          pursuer_policy: area_min
          evader_policy: centroid
          exit_point: null         # [x, y]: evaders escape there (engagement v2); null: no escapes
        vary:                      # each block present is one axis of a cartesian product
          grid: {n_pursuers: [1, 2, 3], evader_policy: [centroid, constant_area]}
          zip: {capture_radius: [0.2, 0.3], dt: [0.01, 0.005]}     # lists in step
          random: {n: 8, ranges: {capture_radius: [0.1, 0.5]}}     # n uniform draws
    """

    # the sweep's name: its metrics' label and the default output folder, results/sweeps/NAME
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = Field(0, ge=0)  # game g of every point is seeded (seed, g); also seeds vary.random
    games_per_point: int = Field(50, ge=1, le=10_000_000)  # Monte Carlo games played at each point
    shard_games: int | None = Field(None, ge=1, le=MAX_SHARD_GAMES)  # games per Ray task; None: from the cost model
    base: dict[str, Any] = {}  # workers.Case fields of the game every point starts from
    vary: VaryModel = VaryModel()  # what changes between points; empty: one point, the base

    @field_validator("base")
    @classmethod
    def _game_names(cls, v):
        check_game_names(v)
        return v

    def _axes(self) -> list[list[dict]]:
        """The product's axes, slowest first: one per grid field, then the zip's rows, then the
        random draws; point i is one value of each, the last axis varying fastest."""
        axes: list[list[dict]] = []
        v = self.vary
        for name, values in (v.grid or {}).items():
            axes.append([{name: x} for x in values])
        if v.zip:
            names = list(v.zip)
            axes.append([dict(zip(names, row)) for row in zip(*v.zip.values())])
        if v.random:
            rng = np.random.default_rng([self.seed, 0x5EED])
            draws = []
            for _ in range(v.random.n):
                d = {}
                for name, (lo, hi) in v.random.ranges.items():
                    d[name] = (int(rng.integers(math.ceil(lo), math.floor(hi) + 1)) if NUMERIC_FIELDS[name] is int
                               else float(rng.uniform(lo, hi)))
                draws.append(d)
            axes.append(draws)
        return axes

    def count(self) -> int:
        """How many points the sweep has, without planning them."""
        return math.prod(len(axis) for axis in self._axes())

    def point(self, index: int, axes: list[list[dict]] | None = None) -> Point:
        """Point `index` (0 <= index < count()) alone; ConfigError naming it when its case is bad."""
        axes = self._axes() if axes is None else axes
        changes: dict = {}
        rest = index
        for axis in reversed(axes):
            rest, k = divmod(rest, len(axis))
            changes = {**axis[k], **changes}
        try:
            case = case_from({**self.base, **changes})
            try:
                case.check_window()  # a sweep's summary reports the "by tau" statistics
            except InputError as e:
                raise ConfigError(str(e), field=e.field) from None
        except ConfigError as e:
            field = str(e).split(":", 1)[0].split(".", 1)[0]
            where = ", ".join(f"{k}={v!r}" for k, v in changes.items())
            prefix = f"vary: point {index} ({where})" if field in changes else "base"
            raise ConfigError(f"{prefix}: {e}") from None
        return Point(index, changes, case, self.games_per_point, self.shard_games or games_per_shard(case))

    def points(self) -> list[Point]:
        """The resolved points of the sweep, in a fixed order (every grid combination, zip row
        and random draw; the last block varying fastest)."""
        axes = self._axes()
        return [self.point(i, axes) for i in range(math.prod(len(axis) for axis in axes))]

    def check(self) -> None:
        """Validate the sweep's points: all of them up to FULL_CHECK_POINTS, else each value
        of each axis once (the rest when the sweep runs)."""
        axes = self._axes()
        total = math.prod(len(axis) for axis in axes)
        if total <= FULL_CHECK_POINTS:
            indexes = range(total)
        else:  # point i with axis j at value k and every other axis at its first value
            strides = [math.prod(len(x) for x in axes[j + 1:]) for j in range(len(axes))]
            indexes = sorted({k * strides[j] for j, axis in enumerate(axes) for k in range(len(axis))})
        for i in indexes:
            self.point(i, axes)

    def size(self) -> JobSize:
        """Points, games and CPU seconds by the cost model (a sample of at most 64 points)."""
        axes = self._axes()
        total = math.prod(len(axis) for axis in axes)
        sample = sorted({round(k * (total - 1) / 63) for k in range(64)}) if total > 64 else range(total)
        mean = float(np.mean([game_seconds(self.point(i, axes).case) for i in sample]))
        return JobSize("sweep", total, "point", total * self.games_per_point, mean * total * self.games_per_point,
                       total * ITEM_BYTES)

    def sweep_id(self, points: list[Point] | None = None) -> str:
        """Hash of the resolved sweep: every point's case key (engine version inside), games,
        shards, the seed and the seeding rule. points: self.points() when already made."""
        points = self.points() if points is None else points
        blob = json.dumps(
            {"seed": self.seed, "points": [p.identity() for p in points], "engine": ENGINE_VERSION,
             "seeding": SEEDING},
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


class Point:
    """One point of a sweep: its index, what it changes, its Case, and its shards."""

    def __init__(self, index: int, changes: dict, case: Case, games: int, shard_games: int):
        self.index, self.changes, self.case = index, changes, case
        self.games, self.shard_games = games, shard_games

    def shards(self) -> list[tuple[int, int, int]]:
        """(shard number, first game, end game) of every shard of the point."""
        return [(k, a, b) for k, (a, b) in enumerate(shard_ranges(self.games, self.shard_games))]

    def identity(self) -> dict:
        """What of the point goes into the sweep's id: index, case key, games and games per shard."""
        return {"index": self.index, "case": self.case.key(), "games": self.games, "shard_games": self.shard_games}


def load_sweep_config(path) -> SweepConfig:
    """Read and validate a sweep YAML; raises ConfigError with one line."""
    return load_yaml_model(path, SweepConfig, "sweep", check=SweepConfig.check)
