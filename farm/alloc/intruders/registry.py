"""The intruder policies' registry, beside the allocators' (farm.alloc.policies.registry): every
intruder policy listed once and made one way.

An entry is a name, a kind (`law`, `heuristic`, `learned`, `mixture` or `search`) and a maker,
`make(config, **options) -> policy`: config is the map's AllocConfig, options the policy's own
keywords (a learned policy's `run`); a maker with a `client` keyword is also given the caller's
capture-time client (a policy that plans on the engagements). A policy answers `routing(D, I) -> (up, down)`: D, I:
(B, N^2) float64 the defenders it sees and the intruders; up, down: (B, N^2) float64 each
cell's share of intruder mass sent up-left and down-left, the rest going straight left
(farm.alloc.model.route_intruders_many). An IntruderSpec carries an entry to a Ray worker, as a
PolicySpec carries an allocator's.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable

from farm.core.errors import ConfigError
from farm.core.pickling import dumps_by_value

__all__ = ["KINDS", "IntruderEntry", "IntruderSpec", "register_intruders", "unregister_intruders",
           "intruder_entry", "intruder_names", "make_intruders"]

KINDS = ("law", "heuristic", "learned", "mixture", "search")
_REGISTRY: dict[str, IntruderEntry] = {}


@dataclass(frozen=True)
class IntruderEntry:
    """One intruder policy: name, kind (one of KINDS), make (see the module doc), description."""

    name: str
    kind: str
    make: Callable[..., Any]
    description: str = ""

    def options(self) -> list[str]:
        """The keyword options make accepts (its parameters but config and client)."""
        params = inspect.signature(self.make).parameters.values()
        return [p.name for p in params
                if p.name not in ("config", "client") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

    def takes_client(self) -> bool:
        """Whether make takes the caller's capture-time client (a `client` keyword)."""
        return "client" in inspect.signature(self.make).parameters


@dataclass(frozen=True)
class IntruderSpec:
    """An intruder policy to make elsewhere (a Ray task): its entry and its options."""

    entry: IntruderEntry
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The entry's name."""
        return self.entry.name

    def make(self, config, client=None):
        """The intruder policy for config's map (client: the capture-time client, for a policy taking one)."""
        extra = {"client": client} if self.entry.takes_client() else {}
        return self.entry.make(config, **self.options, **extra)

    def __reduce__(self):
        return _spec_from_bytes, (dumps_by_value((self.entry, self.options)),)


def _spec_from_bytes(data: bytes) -> IntruderSpec:
    import cloudpickle

    entry, options = cloudpickle.loads(data)
    return IntruderSpec(entry, options)


def register_intruders(name: str, make: Callable[..., Any], *, kind: str, description: str = "",
                       replace: bool = False) -> IntruderEntry:
    """Add an intruder policy to the registry (at the end of its order); returns its entry. A name
    taken already is refused (ValueError) unless replace."""
    if kind not in KINDS:
        raise ValueError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
    if name in _REGISTRY and not replace:
        raise ValueError(f"an intruder policy named {name!r} is registered already")
    entry = IntruderEntry(name, kind, make, description or (inspect.getdoc(make) or "").split("\n")[0])
    _REGISTRY[name] = entry
    return entry


def unregister_intruders(name: str) -> None:
    """Take an intruder policy out of the registry (tests that register their own)."""
    _REGISTRY.pop(name, None)


def intruder_names(kinds: str | tuple[str, ...] = KINDS) -> list[str]:
    """The registered intruder policies of the given kinds, in registration order."""
    kinds = (kinds,) if isinstance(kinds, str) else kinds
    return [name for name, entry in _REGISTRY.items() if entry.kind in kinds]


def intruder_entry(name, field_name: str = "intruders") -> IntruderEntry:
    """The entry of a name; ConfigError (one line naming field_name and the choices) for an unknown one."""
    entry = _REGISTRY.get(name) if isinstance(name, str) else None
    if entry is None:
        raise ConfigError(f"{field_name}: unknown intruder policy {name!r} (choose from {', '.join(_REGISTRY)})",
                          field=field_name)
    return entry


def make_intruders(name: str, config, client=None, **options):
    """The intruder policy `name` for the AllocConfig config (client: the capture-time client, given
    to a policy that takes one); an unknown option is a ConfigError naming `intruder_options`."""
    entry = intruder_entry(name)
    unknown = sorted(set(options) - set(entry.options()))
    if unknown:
        raise ConfigError(f"intruder_options: {name} has no option {unknown[0]!r} (options: "
                          f"{', '.join(entry.options()) or 'none'})", field="intruder_options")
    return IntruderSpec(entry, options).make(config, client)
