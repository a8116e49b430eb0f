"""The allocators' registry: every allocator, heuristic, planner or learned, listed once and
made one way.

An entry is a name, a kind (`baseline`, `planner`, `learned` or `mixture`) and a maker,
`make(config, client, **options) -> allocator`: config is the scenario's AllocConfig, client
the CaptureTimeClient answering its engagements (a baseline ignores it), options the
allocator's own keywords (a planner's `horizon`, a learned allocator's trained `policy`).
An allocator answers SB3's `predict(obs, state=None, episode_start=None, deterministic=True)
-> (action, state)`. The commands, the benchmarks and the report take their lists from here
(policy_names), in registration order.

Entries travel to Ray workers inside the tasks that use them (a PolicySpec holds its entry),
pickled with cloudpickle, the maker's module by value when it is the user's own code (not
farm's, not an installed package: a script, a notebook, a test file, which a worker could not
import by name): an allocator registered in a driver's own module is evaluated on the farm too.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from farm.core.errors import ConfigError
from farm.core.pickling import dumps_by_value

__all__ = ["PolicyEntry", "PolicySpec", "KINDS", "register_policy", "unregister_policy", "policy_entry",
           "policy_names", "make_policy", "check_options", "CHECKED_KINDS"]

CHECKED_KINDS = ("baseline", "planner")  # the allocators check_options builds: those made from their options alone

KINDS = ("baseline", "planner", "learned", "mixture")
_REGISTRY: dict[str, PolicyEntry] = {}


@dataclass(frozen=True)
class PolicyEntry:
    """One allocator: name, kind (one of KINDS), make (see the module doc), description, and
    reference: whether evaluations compare every trained allocator with it by default (a
    baseline or planner that is slow or needs options, like `subregions`, is not)."""

    name: str
    kind: str
    make: Callable[..., Any]
    description: str = ""
    reference: bool = True

    def options(self) -> list[str]:
        """The keyword options make accepts (its parameters but config and client)."""
        params = inspect.signature(self.make).parameters.values()
        return [p.name for p in params if p.name not in ("config", "client")
                and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


@dataclass(frozen=True)
class PolicySpec:
    """An allocator to make elsewhere (a Ray task, a Tune trial): its entry and its options."""

    entry: PolicyEntry
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The entry's name."""
        return self.entry.name

    def make(self, config, client):
        """The allocator."""
        return self.entry.make(config, client, **self.options)

    def __reduce__(self):
        return _spec_from_bytes, (dumps_by_value((self.entry, self.options)),)


def _spec_from_bytes(data: bytes) -> PolicySpec:
    import cloudpickle

    entry, options = cloudpickle.loads(data)
    return PolicySpec(entry, options)


def register_policy(name: str, make: Callable[..., Any], *, kind: str, description: str = "",
                    replace: bool = False, reference: bool = True) -> PolicyEntry:
    """Add an allocator to the registry (at the end of its order); returns its entry. A name
    taken already is refused (ValueError) unless replace. reference: see PolicyEntry."""
    if kind not in KINDS:
        raise ValueError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
    if name in _REGISTRY and not replace:
        raise ValueError(f"an allocator named {name!r} is registered already")
    entry = PolicyEntry(name, kind, make, description or (inspect.getdoc(make) or "").split("\n")[0], reference)
    _REGISTRY[name] = entry
    return entry


def unregister_policy(name: str) -> None:
    """Take an allocator out of the registry (tests that register their own)."""
    _REGISTRY.pop(name, None)


def policy_names(kinds: str | tuple[str, ...] = KINDS, *, references: bool = False) -> list[str]:
    """The registered allocators of the given kinds, in registration order (references: only
    those that evaluations compare with by default, PolicyEntry.reference)."""
    kinds = (kinds,) if isinstance(kinds, str) else kinds
    return [name for name, entry in _REGISTRY.items() if entry.kind in kinds and (entry.reference or not references)]


def policy_entry(name: str, field_name: str = "policy") -> PolicyEntry:
    """The entry of a name; ConfigError (one line naming field_name and the choices) for an unknown one."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(f"{field_name}: unknown allocator {name!r} (choose from {', '.join(_REGISTRY)})",
                          field=field_name) from None


def make_policy(name: str, config, client=None, **options):
    """The allocator `name` for the AllocConfig config, planning on client's statistics."""
    return policy_entry(name).make(config, client, **options)


class _Unasked:
    """A capture-time backend for building allocators to check their options: never asked."""

    repeatable = True

    def get_many(self, keys, estimate=False):
        raise RuntimeError("an allocator asked for statistics while being built")

    def warm(self, keys, progress=None):
        raise RuntimeError("an allocator asked for statistics while being built")


def check_options(name: str, options: dict, config, field: str) -> None:
    """ConfigError (one line naming field) when the allocator `name` refuses `options` on the
    AllocConfig config's map: an option its maker does not take, or a value its own checks
    refuse (a planner's horizon of 0, a degenerate power). The allocator is built as it would be
    for the work, with a capture-time client that is never asked (building asks no statistics),
    so its own checks decide, before any work. Allocators of other kinds than CHECKED_KINDS (a
    learned one, a mixture, which read run folders) are left to their first use."""
    from farm.core.errors import SwarmFarmError
    from farm.service.client import CaptureTimeClient

    entry = policy_entry(name, field)
    if entry.kind not in CHECKED_KINDS:
        return
    allowed = entry.options()
    for option in options:
        if option not in allowed:
            raise ConfigError(f"{field}: {name} has no option {option!r} (options: {', '.join(allowed) or 'none'})",
                              field=field)
    client = CaptureTimeClient(config.game_settings(), backend=_Unasked())
    try:
        entry.make(config, client, **options)
    except (SwarmFarmError, TypeError, ValueError) as e:
        problem = getattr(e, "problem", None) or str(e)
        raise ConfigError(f"{field}: {problem.removeprefix(f'{name}: ')}", field=field) from None
