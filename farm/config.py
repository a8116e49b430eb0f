"""Reading configs: one strict pydantic base, one YAML loader, one way from plain
values to a game (workers.Case), one-line errors naming the field.

A game's settings are workers.Case's fields, with Case's defaults, normalisation
and validation; configs (sweeps, tables, the allocation env) and the CLI name them
and never declare them again.
"""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any, Mapping

import yaml
from pydantic import BaseModel, ConfigDict, TypeAdapter, ValidationError

from workers import GAME_FIELDS, Case, InputError

from farm.errors import ConfigError

__all__ = ["Strict", "ConfigError", "case_from", "check_game_names", "first_line", "load_yaml_model",
           "GAME_FIELDS", "SETTING_FIELDS", "CASE_TYPES", "NUMERIC_FIELDS"]

# A game's settings: every Case field but the team sizes (which a table's or env's cells set).
SETTING_FIELDS = tuple(name for name in GAME_FIELDS if name not in ("n_pursuers", "n_evaders"))
# The type of each of Case's fields; its numeric ones, int or float (what a sweep may draw at random).
CASE_TYPES = typing.get_type_hints(Case)
NUMERIC_FIELDS = {name: t for name, t in CASE_TYPES.items() if name in GAME_FIELDS and t in (int, float)}


class Strict(BaseModel):
    """A config section: unknown keys are errors, values are frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


_CASE = TypeAdapter(Case)


def check_game_names(names, allowed=GAME_FIELDS, where: str = "") -> None:
    """ConfigError unless every name is one of `allowed` (Case's field names by default)."""
    for name in names:
        if name not in allowed:
            raise ConfigError(f"{where}{name}: not a game setting (choose from {', '.join(allowed)})")


def case_from(fields: Mapping[str, Any]) -> Case:
    """The validated Case of plain config values (YAML, JSON or CLI: lists for points,
    a mapping for the law): pydantic checks names and types, Case.validate the values.
    Raises ConfigError (one line naming the field)."""
    check_game_names(fields)
    try:
        return _CASE.validate_python(dict(fields)).validate()
    except ValidationError as e:
        raise ConfigError(first_line(e)) from None
    except InputError as e:
        raise ConfigError(str(e)) from None


def first_line(e: Exception) -> str:
    """'field.sub: problem' of a pydantic error, else the first line of the message."""
    if isinstance(e, ValidationError):
        err = e.errors()[0]
        loc = ".".join(str(x) for x in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        return f"{loc}: {msg}" if loc else msg
    return str(e).splitlines()[0]


def load_yaml_model(path: str | Path, model: type[BaseModel], what: str, check=None):
    """Read a YAML mapping into a typed model, then run check(config) (deeper validation)
    if given; any problem is a ConfigError of one line naming the file."""
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
        raise ConfigError(f"{path}: {first_line(e)}") from None
    except (TypeError, InputError, ConfigError) as e:
        raise ConfigError(f"{path}: {e}") from None
