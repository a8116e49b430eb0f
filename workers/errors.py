"""The project's one error family, and the input checks that raise it.

Every error a user can cause (a bad argument, config, flag, file or cluster address)
is a SwarmFarmError whose message is one line naming the field and the problem; the
`farm` command prints that line and nothing else. `farm` defines its own kinds
(ConfigError, SweepError, ...) as subclasses.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SwarmFarmError", "InputError", "positive", "point"]


class SwarmFarmError(Exception):
    """Base of every error the user can cause; str(e) is one line."""


class InputError(SwarmFarmError, ValueError):
    """Bad input to the engine or the Monte Carlo layer: names the argument and the problem."""


def positive(name: str, value) -> float:
    """value as a float; InputError unless it is a positive finite number (not a bool)."""
    try:
        x = math.nan if isinstance(value, (bool, np.bool_, str)) else float(value)
    except (TypeError, ValueError):
        x = math.nan
    if not math.isfinite(x) or x <= 0:
        raise InputError(f"{name}: must be positive and finite, got {value!r}")
    return x


def point(name: str, value) -> np.ndarray:
    """value as a (2,) float64 array; InputError unless it is a finite point (x, y)."""
    try:
        p = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: must be a finite point (x, y), got {value!r}") from None
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise InputError(f"{name}: must be a finite point (x, y), got {value!r}")
    return p
