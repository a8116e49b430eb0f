"""The game model: a game's parameters (Case), how its initial positions are drawn
(InitialLaw), and the one place every setting's default is defined.

`Case` is the one definition of a game's parameters, with their defaults,
normalisation and validation; configs, the service's keys and the CLI are built
from it, and the engine's own defaults are Case's (`case_defaults`)
(docs/model.md sections 1-4).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import MISSING, asdict, dataclass, field
from typing import Literal

import numpy as np

from workers.arena import make_arena
from workers.errors import InputError, all_numbers, exact, is_number, not_a_number_hint, point, positive, shown, whole
from workers.policies import get_evader_policy, get_pursuer_policy
from workers.version import ENGINE_VERSION

__all__ = ["InitialLaw", "PAPER_LAW", "Case", "GAME_FIELDS", "case_defaults"]

Box = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max
# Field names by kind, for normalisation and validation (Case's numbers).
_POSITIVE_FIELDS = ("capture_radius", "dt", "t_max", "tau", "pursuer_speed", "evader_speed")
_POINT_FIELDS = ("target", "exit_point")
MAX_TEAM = 1_000_000  # agents a team: far above any game played (the allocation env's cells: 100 000)


@dataclass(frozen=True)
class InitialLaw:
    """How initial positions are drawn, independently and uniformly.

    kind "boxes": pursuers in pursuer_box, evaders in evader_box (each
    (x_min, x_max, y_min, y_max)); kind "uniform": everyone uniform in the arena.
    """

    __pydantic_config__ = {"extra": "forbid"}  # read from configs by pydantic: unknown names are errors

    kind: Literal["boxes", "uniform"] = "boxes"  # boxes: each team in its box; uniform: all uniform in the arena
    pursuer_box: Box = (3.0, 5.0, 0.0, 10.0)  # (x_min, x_max, y_min, y_max) of the pursuers' start (kind boxes)
    evader_box: Box = (7.0, 9.0, 0.0, 10.0)  # (x_min, x_max, y_min, y_max) of the evaders' start (kind boxes)


PAPER_LAW = InitialLaw()


@dataclass(frozen=True)
class Case:
    """A game's parameters: everything that changes a Monte Carlo case's numbers.

    docs/model.md section 4; the engine's version is included. Build with Case(n_p, n_e,
    **settings) from code, or with farm.core.config.case_from(mapping) from config values.
    Numbers are normalised on construction (60 and 60.0 give the same Case and key);
    `validate` checks them."""

    __pydantic_config__ = {"extra": "forbid"}  # read from configs by pydantic: unknown names are errors

    n_pursuers: int  # pursuers in the game, 1 to MAX_TEAM
    n_evaders: int  # evaders in the game, 1 to MAX_TEAM
    pursuer_policy: str = "area_min"  # a registered pursuer policy: area_min, pure_pursuit
    evader_policy: str = "centroid"  # a registered evader policy: centroid, constant_area, target, area_max
    capture_radius: float = 0.25  # r_c: an evader closer than this to a pursuer is captured
    dt: float = 0.01  # the time step (s), explicit Euler
    t_max: float = 60.0  # a game's length (s): it stops after floor(t_max / dt) steps
    tau: float = 5.0  # the engagement window (s) of the "by tau" statistics; changes no game
    target: tuple[float, float] = (0.0, 5.0)  # (x, y) the `target` evader policy heads for
    arena: tuple[tuple[float, float], ...] | None = None  # a convex polygon's vertices; None: the square [0, 10]^2
    law: InitialLaw = field(default_factory=InitialLaw)  # how initial positions are drawn
    exit_point: tuple[float, float] | None = None  # None: no escapes (the paper's games)
    pursuer_speed: float = 1.0  # v_p: the pursuers' speed (arena units per s)
    evader_speed: float = 1.0  # v_e: the evaders' speed (arena units per s)
    engine_version: str = ENGINE_VERSION  # the engine's version, part of the key; not a setting

    def __post_init__(self):
        # One spelling per value, so that 60 and 60.0 give the same key. Only numbers and
        # sequences of them are respelled; anything else (a bool, a string, a ragged list)
        # is kept as given for `validate` to name: constructing never raises.
        def num(v):
            try:
                return float(v) if is_number(v) else v
            except OverflowError:  # an int beyond float's range: validate says so
                return v

        def nums(v):
            return tuple(num(x) for x in v) if _is_sequence(v) else v

        for name in _POSITIVE_FIELDS:
            object.__setattr__(self, name, num(getattr(self, name)))
        for name in ("n_pursuers", "n_evaders"):
            v = getattr(self, name)
            if isinstance(v, np.integer):
                object.__setattr__(self, name, int(v))
        for name in _POINT_FIELDS:
            object.__setattr__(self, name, nums(getattr(self, name)))
        if _is_sequence(self.arena):
            object.__setattr__(self, "arena", tuple(nums(v) for v in self.arena))
        if isinstance(self.law, InitialLaw):
            object.__setattr__(self, "law", InitialLaw(self.law.kind, nums(self.law.pursuer_box),
                                                       nums(self.law.evader_box)))

    def validate(self) -> Case:
        """The Case itself when every setting is valid, else an InputError naming the first bad one.

        Checks the team sizes (whole numbers, not bools, at most MAX_TEAM), the policies'
        names, that the numbers are positive and finite and the points finite (numbers, never
        bools, nested ones too), the arena, that the exit point is in the arena, and the law's
        boxes: four finite numbers, inside the arena when the law draws from them. Every path
        from a Case to a game (run_case, run_games, simulate_case, sample_initial_positions)
        calls it first, so no game is built from a Case it refuses."""
        for name in ("n_pursuers", "n_evaders"):
            v = getattr(self, name)
            whole(name, v, 1)
            if v > MAX_TEAM:
                raise InputError(f"{name}: {shown(v)} agents is more than the engine's limit of {MAX_TEAM}", field=name)
        get_pursuer_policy(self.pursuer_policy)
        get_evader_policy(self.evader_policy)
        for name in _POSITIVE_FIELDS:
            positive(name, getattr(self, name))
        for name in _POINT_FIELDS:
            if name != "exit_point" or self.exit_point is not None:
                point(name, getattr(self, name))
        arena = make_arena(self.arena)
        if self.exit_point is not None:
            check_exit_point(point("exit_point", self.exit_point), arena)
        if not isinstance(self.law, InitialLaw):
            raise InputError(f"law: expected a workers.InitialLaw, got {type(self.law).__name__}", field="law")
        if not isinstance(self.law.kind, str) or self.law.kind not in ("boxes", "uniform"):
            raise InputError(f"law.kind: must be 'boxes' or 'uniform', got {shown(self.law.kind)}", field="law.kind")
        for name in ("pursuer_box", "evader_box"):
            box = getattr(self.law, name)
            if not _is_box(box):
                raise InputError(f"law.{name}: must be (x_min, x_max, y_min, y_max), finite numbers, "
                                 f"got {shown(box)}{not_a_number_hint(box)}", field=f"law.{name}")
            corners = np.array([[box[0], box[2]], [box[1], box[2]], [box[1], box[3]], [box[0], box[3]]])
            if self.law.kind == "boxes" and not arena.contains(corners).all():
                raise InputError(f"law.{name}: {shown(box)} is not inside the arena", field=f"law.{name}")
        return self

    def check_window(self) -> Case:
        """The Case itself when its statistics window fits its games (tau <= t_max), else an
        InputError naming tau: the "by tau" statistics (frac_captured_tau, capture_score_tau)
        of games shorter than tau would count captures the games never reach. The game itself
        does not need it (tau changes no game): the statistics' callers check it (run_case,
        the service's keys, a sweep's points)."""
        if self.tau > self.t_max + 1e-9:
            raise InputError(f"tau: the statistics window ({self.tau:g} s) is longer than the games (t_max = "
                             f"{self.t_max:g} s); set tau <= t_max", field="tau")
        return self

    def to_dict(self) -> dict:
        """Every field as plain JSON values (tuples become lists, the law a dict)."""
        return json.loads(json.dumps(asdict(self)))

    def key(self) -> str:
        """A stable hash of every parameter, the engine's version included."""
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _is_sequence(v) -> bool:
    """True for a tuple, list or array of at least one dimension (what Case respells)."""
    return isinstance(v, (tuple, list)) or (isinstance(v, np.ndarray) and v.ndim >= 1)


def _is_box(box) -> bool:
    """True for (x_min, x_max, y_min, y_max): four finite numbers (no bools), min <= max."""
    if not (_is_sequence(box) and len(box) == 4 and all_numbers(box)):
        return False
    try:
        b = np.array(box, dtype=np.float64)
    except (ValueError, OverflowError):  # ragged, or an int beyond float's range
        return False
    return b.shape == (4,) and bool(np.all(np.isfinite(b))) and b[0] <= b[1] and b[2] <= b[3]


def check_exit_point(exit_xy: np.ndarray, arena) -> None:
    """InputError unless the exit point (2,) float64 is in the arena (or on its boundary):
    no evader could reach one outside. The message prints the coordinates exactly."""
    if not arena.contains(exit_xy):
        raise InputError(f"exit_point: ({exact(exit_xy[0])}, {exact(exit_xy[1])}) is outside the arena",
                         field="exit_point")


# The game settings a config may name (the engine's version is not a setting).
GAME_FIELDS = tuple(name for name in Case.__dataclass_fields__ if name != "engine_version")


def case_defaults(**given) -> list:
    """The values given, each None replaced by Case's default for that name.

    Case is the one place a game setting's default is defined. Names are Case's fields;
    a value that is not None, and a field without a default, is returned as given, in the
    order given."""
    fields = Case.__dataclass_fields__
    return [fields[name].default if v is None and fields[name].default is not MISSING else v
            for name, v in given.items()]
