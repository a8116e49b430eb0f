"""What the capture-time service is asked: the key of a case's statistics.

A key holds everything that changes the numbers (docs/model.md section 4): the
workers.Case (team sizes, policies, arena, r_c, dt, t_max, tau, target, initial-position
law, exit point, team speeds and the engine's version), games per case and the seed, so
stale results are never served after the engine changes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from functools import cached_property

from farm.core.checks import whole
from farm.core.config import SETTING_FIELDS
from workers import Case, InputError

__all__ = ["GameSettings", "StatsKey", "SERVICE_FIELDS", "LATTICE", "lattice_anchors"]

SERVICE_FIELDS = ("games", "seed")  # a key's settings beyond its game's
# The lattice of team sizes, about a factor 1.5 apart: the allocation env's `team_sizes:
# lattice` snaps to it (farm.alloc.game.model), and `estimates: lattice` interpolates between it.
LATTICE = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)


def _bracket(n: int) -> tuple[int, ...]:
    """The lattice sizes around a team size n >= 1: (n,) on the lattice, else the one below and
    the one above (above 256: 256 alone)."""
    if n in LATTICE or n >= LATTICE[-1]:
        return (min(n, LATTICE[-1]),)
    below = max(v for v in LATTICE if v < n)
    return below, min(v for v in LATTICE if v > n)


def lattice_anchors(n_pursuers: int, n_evaders: int) -> list[tuple[int, int]]:
    """The lattice pairs around a team-size pair: itself when both sizes are on the lattice,
    else the 2 or 4 corners of the lattice cell holding it (sizes above 256 anchored at 256)."""
    return [(p, e) for p in _bracket(n_pursuers) for e in _bracket(n_evaders)]


@dataclass(frozen=True)
class GameSettings:
    """Everything of a key but the team sizes: the game (a workers.Case whose team
    sizes are replaced by each key's), games and seed."""

    game: Case = field(default_factory=lambda: Case(1, 1))
    games: int = 64
    seed: int = 0

    @classmethod
    def of(cls, **fields) -> GameSettings:
        """GameSettings.of(games=16, t_max=10.0, evader_policy="centroid"): games, seed and
        Case fields by name; the rest at their defaults."""
        return cls().with_(**fields)

    def key(self, n_pursuers: int, n_evaders: int) -> StatsKey:
        """The StatsKey of one team-size pair under these settings; InputError (one line) for bad
        games, seed or sizes, or a window tau longer than the games (Case.check_window)."""
        whole("games", self.games, 2, error=InputError)
        whole("seed", self.seed, 0, error=InputError)
        case = replace(self.game, n_pursuers=n_pursuers, n_evaders=n_evaders).validate().check_window()
        return StatsKey(case, self.games, self.seed)

    def with_(self, **changes) -> GameSettings:
        """A copy with games, seed or any Case field changed."""
        own = {k: changes.pop(k) for k in SERVICE_FIELDS if k in changes}
        _known(changes)
        return replace(self, game=replace(self.game, **changes) if changes else self.game, **own)


def _known(game: dict) -> None:
    """Case fields other than the team sizes (which each key sets) are settings."""
    unknown = sorted(set(game) - set(SETTING_FIELDS))
    if unknown:
        raise InputError(f"GameSettings: not a game setting: {', '.join(unknown)}")


@dataclass(frozen=True)
class StatsKey:
    """One case's statistics: the Case (engine version inside), games and seed."""

    case: Case
    games: int
    seed: int

    @property
    def sizes(self) -> tuple[int, int]:
        """(n_pursuers, n_evaders) of the key's case."""
        return self.case.n_pursuers, self.case.n_evaders

    def to_dict(self) -> dict:
        """The key as plain JSON values: {"case": Case.to_dict(), "games", "seed"}."""
        return {"case": self.case.to_dict(), "games": self.games, "seed": self.seed}

    @cached_property
    def _digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()

    def digest(self) -> str:
        """SHA-256 (hex) of the key's JSON: its row id in the store."""
        return self._digest

    def settings_digest(self) -> str:
        """16 hex digits identifying everything of the key but the team sizes (its neighbours for
        estimates share it)."""
        d = self.to_dict()
        d["case"] = {k: v for k, v in d["case"].items() if k not in ("n_pursuers", "n_evaders")}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]

