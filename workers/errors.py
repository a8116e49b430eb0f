"""The project's one error family, and the input checks that raise it.

Every error a user can cause (a bad argument, config, flag, file or cluster address)
is a SwarmFarmError whose message is one line naming the field and the problem; the
`farm` command prints that line and nothing else. `farm` defines its own kinds
(ConfigError, SweepError, ...) as subclasses.

A number here is a real number: an int or a float (numpy's too), never a bool, a string,
None or a complex; settings must also be finite. Input that is valid but likely to give
misleading numbers (a coarse time step) is a CoarseStepWarning, not an error.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["SwarmFarmError", "InputError", "CoarseStepWarning", "positive", "point", "whole", "is_number", "is_whole",
           "is_finite_number", "is_positive", "all_numbers", "not_a_number_hint", "shown", "exact"]


class SwarmFarmError(Exception):
    """Base of every error the user can cause; str(e) is one line.

    field: the setting the error is about, when the raiser names one (the CLI maps it to
    its flag); the message then starts with `<field>: `, and `problem` is the rest."""

    def __init__(self, *args, field: str | None = None):
        super().__init__(*args)
        if field is not None and not str(self).startswith(f"{field}: "):
            raise ValueError(f"an error about {field!r} must start with '{field}: ', got {str(self)!r}")
        self.field = field

    @property
    def problem(self) -> str:
        """The message without its `<field>: ` (the whole message without a field)."""
        return str(self)[len(self.field) + 2:] if self.field is not None else str(self)


class InputError(SwarmFarmError, ValueError):
    """Bad input to the engine or the Monte Carlo layer: names the argument and the problem."""


class CoarseStepWarning(UserWarning):
    """A time step so long that an agent moves more than the capture radius in one step:
    captures may come late or be missed (the game's numbers are the coarse model's)."""


def is_number(value) -> bool:
    """True for a real number (int, float, Fraction, numpy's integers and floats), False for
    a bool (numpy's too), a string, None, a complex or anything else."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def is_whole(value, *, numpy: bool = True) -> bool:
    """True for a whole number: an int, or one of numpy's integers unless numpy is False;
    False for a bool (an int to Python), a float, even 3.0, and anything else."""
    return isinstance(value, (int, np.integer) if numpy else int) and not isinstance(value, bool)


def is_finite_number(value) -> bool:
    """True for a number (is_number) that is finite: not inf, -inf or NaN."""
    return is_number(value) and math.isfinite(value)


def is_positive(value) -> bool:
    """True for a positive finite number (is_finite_number and > 0)."""
    return is_finite_number(value) and value > 0


def all_numbers(value) -> bool:
    """True when value is a number, or a (nested) list, tuple or array holding numbers only
    (no bool, string, None or complex anywhere; numpy would silently turn True into 1.0)."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iuf":
            return True
        return value.dtype.kind == "O" and all(all_numbers(x) for x in value.flat)
    if isinstance(value, (list, tuple)):
        return all(all_numbers(x) for x in value)
    return is_number(value)


def shown(value, limit: int = 80) -> str:
    """repr(value) for a one-line message: whitespace runs (an array's line breaks) become
    one space, and a repr longer than `limit` characters is cut with "..."; an integer (or a
    container of one) past Python's limit on printing integers (4,300 digits) is named by its size."""
    try:
        text = " ".join(repr(value).split())
    except ValueError:
        digits = int(abs(value).bit_length() * 0.30103) + 1 if isinstance(value, int) else None
        text = (f"an integer of about {digits:,} digits" if digits is not None
                else f"a {type(value).__name__} holding an integer too long to print")
    return text if len(text) <= limit else text[: limit - 3] + "..."


def exact(x: float) -> str:
    """x for a message, exactly: short (:g) when that reads back as x, else its repr (10.0000001,
    not 10, which would show a point just outside the arena as inside)."""
    text = f"{float(x):g}"
    return text if float(text) == float(x) else repr(float(x))


def not_a_number_hint(value) -> str:
    """" (a bool is not a number)" when value holds a bool anywhere, else "": for messages."""
    def has_bool(v):
        if isinstance(v, (bool, np.bool_)):
            return True
        if isinstance(v, np.ndarray):
            return v.dtype.kind == "b" or (v.dtype.kind == "O" and any(has_bool(x) for x in v.flat))
        return isinstance(v, (list, tuple)) and any(has_bool(x) for x in v)

    return " (a bool is not a number)" if has_bool(value) else ""


def positive(name: str, value) -> float:
    """value as a float; InputError unless it is a positive finite number (not a bool)."""
    try:
        x = float(value) if is_number(value) else math.nan
    except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond float's range
        x = math.nan
    if not math.isfinite(x) or x <= 0:
        raise InputError(f"{name}: must be positive and finite, got {shown(value)}{not_a_number_hint(value)}",
                         field=name)
    return x


def whole(name: str, value, least: int) -> int:
    """value as an int; InputError unless it is a whole number >= least (is_whole: never a bool)."""
    if not is_whole(value) or value < least:
        raise InputError(f"{name}: must be a whole number >= {least}, got {shown(value)}", field=name)
    return int(value)


def point(name: str, value) -> np.ndarray:
    """value as a (2,) float64 array; InputError unless it is a finite point (x, y) of numbers."""
    try:
        if not all_numbers(value):
            raise TypeError
        p = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        hint = not_a_number_hint(value)
        raise InputError(f"{name}: must be a finite point (x, y), got {shown(value)}{hint}", field=name) from None
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise InputError(f"{name}: must be a finite point (x, y), got {shown(value)}", field=name)
    return p
