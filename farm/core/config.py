"""Reading configs: one strict pydantic base, one YAML loader, one way from plain
values to a game (workers.Case), one-line errors naming the field.

A game's settings are workers.Case's fields, with Case's defaults, normalisation
and validation; configs (sweeps, tables, the allocation env) and the CLI name them
and never declare them again.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from farm.core.errors import ConfigError
from workers import GAME_FIELDS, Case, InputError

__all__ = ["Strict", "StrictFile", "refuse_unknown_keys", "ConfigError", "case_from", "check_game_names", "first_line",
           "load_yaml_model", "read_yaml", "MAX_CONFIG_BYTES", "MAX_CONFIG_DEPTH", "MAX_CONFIG_VALUES",
           "error_field", "GAME_FIELDS", "SETTING_FIELDS", "CASE_TYPES", "NUMERIC_FIELDS", "find_bool",
           "find_non_finite"]

# A game's settings: every Case field but the team sizes (which a table's or env's cells set).
SETTING_FIELDS = tuple(name for name in GAME_FIELDS if name not in ("n_pursuers", "n_evaders"))
# The type of each of Case's fields; its numeric ones, int or float (what a sweep may draw at random).
CASE_TYPES = typing.get_type_hints(Case)
NUMERIC_FIELDS = {name: t for name, t in CASE_TYPES.items() if name in GAME_FIELDS and t in (int, float)}


def _find(value, hit, where: str, seen: set | None = None) -> str | None:
    """Where in a plain value (nested lists, tuples, mappings, dataclasses) the first leaf with
    hit(leaf) is: "" for the value itself, "[1]" or ".key[0]" inside it; None without one.
    Each container is walked once (YAML aliases may repeat one node, or hold it in itself)."""
    if hit(value):
        return where
    seen = set() if seen is None else seen
    if id(value) in seen:
        return None
    node = value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    seen.add(id(node))  # node lives as long as the value walked: its id is never reused meanwhile
    for key, item in items:
        found = _find(item, hit, f"{where}.{key}" if isinstance(value, Mapping) else f"{where}[{key}]", seen)
        if found is not None:
            return found
    return None


def find_bool(value, where: str = "") -> str | None:
    """Where the first boolean in a plain value (nested lists, tuples, mappings) is: `where`
    for the value itself, where + "[1]" or where + ".key[0]" inside it; None without one."""
    return _find(value, lambda x: isinstance(x, (bool, np.bool_)), where)


def find_non_finite(value, where: str = "") -> str | None:
    """Where the first NaN or infinite number in a plain value (nested lists, tuples, mappings,
    dataclasses) is, as find_bool says it; None when every number is finite."""
    return _find(value, lambda x: isinstance(x, (float, np.floating)) and not math.isfinite(x), where)


def _at(where: str) -> str:
    return f" (at {where.lstrip('.')})" if where else ""


@functools.cache
def _checked_elsewhere(annotation) -> bool:
    """Whether a field's type is or holds a pydantic model (a config section, checked by its
    own validators) or Any (values checked where they are used: case_from for game
    settings, the field's own validator otherwise)."""
    if annotation is Any or (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
        return True
    return any(_checked_elsewhere(arg) for arg in typing.get_args(annotation) if arg is not Ellipsis)


@functools.cache
def _takes_bool(annotation) -> bool:
    """Whether a field's type may hold a boolean, at any depth; a dataclass's field types
    are looked into."""
    if annotation is bool:
        return True
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        return any(_takes_bool(t) for t in typing.get_type_hints(annotation).values())
    if typing.get_origin(annotation) is typing.Literal:
        return any(isinstance(v, bool) for v in typing.get_args(annotation))
    return any(_takes_bool(arg) for arg in typing.get_args(annotation) if arg is not Ellipsis)


def refuse_unknown_keys(model: type[BaseModel], data, what: str):
    """A `mode="before"` model validator's body: data unchanged, or ValueError naming the first
    key of a mapping that is not one of model's fields, its value and the fields to choose from
    (`what`: the config's kind, "a suite" or "an experiments")."""
    if isinstance(data, dict):
        for key in data:
            if key not in model.model_fields:
                raise ValueError(f"{key}: not {what} field, got {key!r} = {data[key]!r} "
                                 f"(choose from {', '.join(model.model_fields) or 'none'})")
    return data


class Strict(BaseModel):
    """A config section: unknown keys are errors, values are frozen, every number is finite
    (NaN and infinities refused, in nested values too), and a boolean is never a number (a
    boolean is refused wherever the field's type holds no bool, in nested lists too).

    A field typed Any (free-form, e.g. a sweep's game settings) is checked where its values
    are used: game settings by case_from, which refuses booleans and non-finite numbers too."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _plain_numbers(cls, value, info: ValidationInfo):
        annotation = cls.model_fields[info.field_name].annotation
        if _checked_elsewhere(annotation):
            return value
        if not _takes_bool(annotation):
            where = find_bool(value)
            if where is not None:
                raise ValueError(f"must not be a bool, got {value!r}{_at(where)} (a bool is not a number)")
        where = find_non_finite(value)
        if where is not None:
            raise ValueError(f"must be a finite number, got {value!r}{_at(where)}")
        return value


class StrictFile(Strict):
    """A whole config file's model: Strict, and a key that is none of its fields is one line
    naming the key, its value and the fields (refuse_unknown_keys); KIND names the config
    ("a suite", "an experiments")."""

    KIND: typing.ClassVar[str] = "a"

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data):
        return refuse_unknown_keys(cls, data, cls.KIND)


_CASE = TypeAdapter(Case)


def check_game_names(names, allowed=GAME_FIELDS, where: str = "") -> None:
    """ConfigError unless every name is one of `allowed` (Case's field names by default)."""
    for name in names:
        if name not in allowed:
            raise ConfigError(f"{where}{name}: not a game setting (choose from {', '.join(allowed)})")


def case_from(fields: Mapping[str, Any]) -> Case:
    """The validated Case of plain config values (YAML, JSON or CLI: lists for points,
    a mapping for the law): pydantic checks names and types (text numbers such as the CLI's
    "0.5" read as numbers; a boolean, at any depth, is refused), Case.validate the values
    (every number finite, the arena's and the law's boxes too).
    Raises ConfigError (one line naming the field)."""
    check_game_names(fields)
    for name, value in fields.items():  # pydantic's lax mode would read true as 1
        where = find_bool(value, name)
        if where is not None:
            raise ConfigError(f"{where}: must be a number or a name, got {value!r} (a bool is not a number)",
                              field=where)
    try:
        case = _CASE.validate_python(dict(fields)).validate()
    except ValidationError as e:
        raise ConfigError(first_line(e), field=error_field(e)) from None
    except InputError as e:
        raise ConfigError(str(e), field=e.field) from None
    return case


def error_field(e: ValidationError) -> str | None:
    """The dotted field a pydantic error is about (first_line's), None for the model itself."""
    return ".".join(str(x) for x in e.errors()[0]["loc"]) or None


def first_line(e: Exception) -> str:
    """'field.sub: problem' of a pydantic error, else the first line of the message."""
    if isinstance(e, ValidationError):
        loc, msg = error_field(e), e.errors()[0]["msg"].removeprefix("Value error, ")
        return f"{loc}: {msg}" if loc else msg
    return str(e).splitlines()[0]


MAX_CONFIG_BYTES = 1 << 20  # a config file is text a person wrote: 1 MiB at most
MAX_CONFIG_DEPTH = 50  # mappings and lists nested at most this deep


MAX_CONFIG_VALUES = 100_000  # mappings, lists and scalars a config holds, aliases expanded


class _ConfigLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a key given twice in one mapping (SafeLoader keeps the
    last). Aliases (`*name`, which PyYAML's own dump writes for a value used twice) are
    accepted; read_yaml bounds what they expand to (MAX_CONFIG_VALUES), so that a short file
    cannot stand for gigabytes, and how deep values nest (MAX_CONFIG_DEPTH)."""

    def construct_mapping(self, node, deep=False):
        """A mapping; a key given twice is refused, naming it."""
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
            except TypeError:  # an unhashable key: SafeLoader's own error says so
                break
            if duplicate:
                raise yaml.constructor.ConstructorError(None, None, f"key {key!r} is given twice",
                                                        key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _extent(value) -> tuple[int, int]:
    """(how deep mappings and lists nest in value, how many values it holds with every alias
    expanded), without recursion; the walk stops once either passes its limit, so a value that
    holds itself (a recursive alias) ends too."""
    deepest, count, stack = 0, 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        count += 1
        if count > MAX_CONFIG_VALUES:
            break
        if isinstance(item, dict):
            item = [*item.keys(), *item.values()]
        if isinstance(item, list):
            deepest = max(deepest, depth + 1)
            if depth + 1 > MAX_CONFIG_DEPTH:
                break
            stack.extend((x, depth + 1) for x in item)
    return deepest, count


def read_yaml(path: str | Path):
    """A config file's YAML as plain values; ConfigError of one line naming the file for a
    file that is missing, a folder, larger than MAX_CONFIG_BYTES (/dev/zero is read only that
    far), not UTF-8 YAML, holding a key twice, nesting deeper than MAX_CONFIG_DEPTH, or holding
    more than MAX_CONFIG_VALUES values once its aliases are expanded."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_CONFIG_BYTES >> 20} MiB: not a config file")
    try:
        raw = yaml.load(data.decode("utf-8"), Loader=_ConfigLoader)  # noqa: S506 - a SafeLoader
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not valid YAML (not UTF-8 text)") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested deeper than {MAX_CONFIG_DEPTH} levels: not a config") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        problem = getattr(e, "problem", None)
        why = f": {problem}" if isinstance(e, yaml.constructor.ConstructorError) and problem else ""
        raise ConfigError(f"{path}: not valid YAML{where}{why}") from None
    depth, count = _extent(raw)
    if depth > MAX_CONFIG_DEPTH:
        raise ConfigError(f"{path}: nested deeper than {MAX_CONFIG_DEPTH} levels: not a config")
    if count > MAX_CONFIG_VALUES:
        raise ConfigError(f"{path}: holds more than {MAX_CONFIG_VALUES:,} values once its YAML aliases are "
                          f"expanded: not a config")
    return raw


def load_yaml_model(path: str | Path, model: type[BaseModel], what: str, check=None):
    """Read a YAML mapping (read_yaml) into a typed model, then run check(config) (deeper
    validation) if given; any problem is a ConfigError of one line naming the file."""
    path = Path(path)
    raw = read_yaml(path)
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
