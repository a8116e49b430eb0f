"""The checks of one value that farm makes in many places: a whole number, a positive
finite number, true or false.

A bool is never a number here, though Python counts True as 1: YAML's `yes` and JSON's
`true` are bools, and a config saying `episodes: yes` is refused, not read as 1. The
predicates are the data plane's (workers.errors: is_number, is_whole, is_finite_number,
is_positive), so farm and workers agree on what a number is; `whole` and `flag` raise
the one-line error naming the field, `<field>: must be ..., got <value>`.
"""

from __future__ import annotations

from farm.core.errors import ConfigError, SwarmFarmError
from workers.errors import is_finite_number, is_number, is_positive, is_whole

__all__ = ["is_number", "is_whole", "is_finite_number", "is_positive", "whole", "flag"]


def _refuse(error: type[Exception], field: str, message: str):
    """error(message), naming field when it is one of the project's errors (a plain ValueError,
    raised in a pydantic validator, names none: pydantic adds where it was)."""
    return error(message, field=field) if issubclass(error, SwarmFarmError) else error(message)


def whole(field: str, value, least: int = 0, *, numpy: bool = False, error: type[Exception] = ConfigError) -> int:
    """value as an int; else `error` "<field>: must be a whole number >= <least>, got <value!r>".

    value must be an int (is_whole; numpy's integers too with numpy) and >= least. error:
    ConfigError by default; InputError for a library argument, ValueError in a pydantic
    validator."""
    if not is_whole(value, numpy=numpy) or value < least:
        raise _refuse(error, field, f"{field}: must be a whole number >= {least}, got {value!r}")
    return int(value)


def flag(field: str, value, *, error: type[Exception] = ConfigError) -> bool:
    """value when it is a bool; else `error` "<field>: must be true or false, got <value!r>" (error as for whole)."""
    if not isinstance(value, bool):
        raise _refuse(error, field, f"{field}: must be true or false, got {value!r}")
    return value
