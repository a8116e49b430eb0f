"""A game's start given by hand: the two teams' positions as arrays, from lists of [x, y] pairs
or from a positions document {"pursuers": [[x, y], ...], "evaders": [[x, y], ...]} (`farm game
--positions`). A start drawn by a case's initial-position law is workers.sample_initial_positions'."""

from __future__ import annotations

import json

import numpy as np

from farm.core.checks import is_finite_number
from farm.core.errors import ConfigError

__all__ = ["positions_document", "start_arrays"]

SIDES = ("pursuers", "evaders")


def positions_document(data) -> tuple[list, list]:
    """The pursuers' and the evaders' [x, y] pairs of a positions document (parsed JSON: an object
    with exactly the keys "pursuers" and "evaders"); ConfigError naming positions otherwise, or for
    a position that is not a pair of finite numbers (a bool is not a number)."""
    if not isinstance(data, dict) or not set(SIDES) <= set(data):
        raise ConfigError("positions: JSON must be an object with 'pursuers' and 'evaders' lists of [x, y]",
                          field="positions")
    unknown = sorted(set(data) - set(SIDES))
    if unknown:
        raise ConfigError(f"positions: unknown key {unknown[0]!r} (the JSON holds 'pursuers' and 'evaders' only)",
                          field="positions")
    pursuers, evaders = (_xy_pairs(data[side], side) for side in SIDES)
    return pursuers, evaders


def _xy_pairs(value, side: str) -> list:
    """value when it is a list of [x, y] pairs of finite numbers, else ConfigError naming positions and side."""
    if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 for p in value):
        raise ConfigError(f"positions: {side}: expected a list of [x, y] pairs, got {json.dumps(value)[:60]}",
                          field="positions")
    for p in value:
        if not all(is_finite_number(v) for v in p):
            raise ConfigError(f"positions: {side}: {json.dumps(p)[:60]} is not a pair of finite numbers",
                              field="positions")
    return value


def start_arrays(pursuers, evaders) -> tuple[np.ndarray, np.ndarray]:
    """One game's start: pursuers (1, n_p, 2) and evaders (1, n_e, 2) float64 of two non-empty
    lists (or arrays) of [x, y] pairs; ConfigError naming positions otherwise. Whether the
    positions lie in the arena is the engine's check, when the game is played."""
    try:
        p = np.array(pursuers, dtype=np.float64)[None]
        e = np.array(evaders, dtype=np.float64)[None]
    except (TypeError, ValueError):
        raise ConfigError("positions: expected lists of [x, y] pairs", field="positions") from None
    if p.ndim != 3 or e.ndim != 3 or p.shape[1] == 0 or e.shape[1] == 0:
        raise ConfigError("positions: expected non-empty lists of [x, y] pairs", field="positions")
    return p, e
