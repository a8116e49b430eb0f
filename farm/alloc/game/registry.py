"""The two sides' registries: one Registry class, two instances. ALLOCATORS holds the defenders'
policies (farm.alloc.allocators registers them), INTRUDERS the intruder policies
(farm.alloc.intruders registers them). Where one side plans against the other (minimax's replies,
the `search` intruders' model of the allocators) it asks the other's registry by name, so neither
side's package imports the other's.

Entries travel to Ray workers inside the tasks that use them (a Spec holds its entry), pickled
with cloudpickle, the maker's module by value when it is the user's own code (a script, a
notebook, a test file, which a worker could not import by name): a policy registered in a
driver's own module is played on the farm too.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from farm.core.errors import ConfigError
from farm.core.pickling import dumps_by_value

__all__ = ["Entry", "Spec", "Registry", "ALLOCATORS", "INTRUDERS"]


@dataclass(frozen=True)
class Entry:
    """One policy of a registry: name, kind (one of the registry's kinds), make, description,
    client ("always": make takes the client as its second argument; "if_taken": as a `client`
    keyword when make has one), and reference: whether evaluations compare every
    trained allocator with it by default (a baseline or planner that is slow or needs options,
    like `subregions`, is not).

    An allocator's maker is `make(config, client, **options) -> allocator`, answering SB3's
    `predict(obs, state=None, episode_start=None, deterministic=True) -> (action, state)`; an
    intruder policy's is `make(config, **options) -> policy` (with `client=` when it takes one),
    answering `routing(D, I) -> (up, down)`: D, I: (B, N^2) float64 the defenders it sees and the
    intruders; up, down: (B, N^2) float64 each cell's share of intruder mass sent up-left and
    down-left, the rest straight left (farm.alloc.game.model.route_intruders_many). config is the
    map's AllocConfig, options the policy's own keywords (a planner's `horizon`, a learned
    policy's `run`)."""

    name: str
    kind: str
    make: Callable[..., Any]
    description: str = ""
    reference: bool = True
    client: str = "always"

    def options(self) -> list[str]:
        """The keyword options make accepts (its parameters but config and client)."""
        params = inspect.signature(self.make).parameters.values()
        return [p.name for p in params
                if p.name not in ("config", "client") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

    def build(self, config, client=None, options: dict | None = None):
        """The policy for the AllocConfig config, with its options, given client as make takes it."""
        options = options or {}
        if self.client == "always":
            return self.make(config, client, **options)
        extra = {"client": client} if "client" in inspect.signature(self.make).parameters else {}
        return self.make(config, **options, **extra)


@dataclass(frozen=True)
class Spec:
    """A policy to make elsewhere (a Ray task, a Tune trial): its entry and its options."""

    entry: Entry
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The entry's name."""
        return self.entry.name

    def make(self, config, client=None):
        """The policy for config's map (client: the capture-time client, for a policy taking one)."""
        return self.entry.build(config, client, self.options)

    def __reduce__(self):
        return _spec_from_bytes, (dumps_by_value((self.entry, self.options)),)


def _spec_from_bytes(data: bytes) -> Spec:
    import cloudpickle

    entry, options = cloudpickle.loads(data)
    return Spec(entry, options)


class _Unasked:
    """A capture-time backend for building policies to check their options: never asked."""

    repeatable = True

    def get_many(self, keys, estimate=False):
        raise RuntimeError("a policy asked for statistics while being built")

    def warm(self, keys, progress=None):
        raise RuntimeError("a policy asked for statistics while being built")


class Registry:
    """The policies of one side, listed once and made one way, in registration order.

    noun: what one entry is called in messages ("allocator"); kinds: the kinds an entry may have;
    field: the config field an unknown name is reported against by default; client: how makers
    take the client (Entry.client); options_field: the field an unknown option of make() is
    reported against (None: make() leaves options to the maker); checked_kinds: the kinds
    check_options builds (those made from their options alone)."""

    def __init__(self, noun: str, kinds: tuple[str, ...], *, field: str, client: str,
                 options_field: str | None = None, checked_kinds: tuple[str, ...] = ()):
        self.noun, self.kinds, self.field, self.client = noun, kinds, field, client
        self.options_field, self.checked_kinds = options_field, checked_kinds
        self._entries: dict[str, Entry] = {}

    def register(self, name: str, make: Callable[..., Any], *, kind: str, description: str = "",
                 replace: bool = False, reference: bool = True) -> Entry:
        """Add a policy (at the end of the order); returns its entry. A name taken already is
        refused (ValueError) unless replace. reference: see Entry."""
        if kind not in self.kinds:
            raise ValueError(f"kind: must be one of {', '.join(self.kinds)}, got {kind!r}")
        if name in self._entries and not replace:
            raise ValueError(f"an {self.noun} named {name!r} is registered already")
        entry = Entry(name, kind, make, description or (inspect.getdoc(make) or "").split("\n")[0], reference,
                      self.client)
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> None:
        """Take a policy out (tests that register their own)."""
        self._entries.pop(name, None)

    def names(self, kinds: str | tuple[str, ...] | None = None, *, references: bool = False) -> list[str]:
        """The registered policies of the given kinds (default: all), in registration order
        (references: only those evaluations compare with by default, Entry.reference)."""
        kinds = self.kinds if kinds is None else (kinds,) if isinstance(kinds, str) else kinds
        return [name for name, entry in self._entries.items()
                if entry.kind in kinds and (entry.reference or not references)]

    def entry(self, name, field_name: str | None = None) -> Entry:
        """The entry of a name; ConfigError (one line naming field_name and the choices) for an unknown one."""
        field_name = field_name or self.field
        entry = self._entries.get(name) if isinstance(name, str) else None
        if entry is None:
            raise ConfigError(f"{field_name}: unknown {self.noun} {name!r} (choose from {', '.join(self._entries)})",
                              field=field_name)
        return entry

    def make(self, name: str, config, client=None, **options):
        """The policy `name` for the AllocConfig config, planning on client's statistics."""
        entry = self.entry(name)
        if self.options_field is not None:
            unknown = sorted(set(options) - set(entry.options()))
            if unknown:
                raise ConfigError(f"{self.options_field}: {name} has no option {unknown[0]!r} (options: "
                                  f"{', '.join(entry.options()) or 'none'})", field=self.options_field)
        return entry.build(config, client, options)

    def check_options(self, name: str, options: dict, config, field: str) -> None:
        """ConfigError (one line naming field) when the policy `name` refuses `options` on the
        AllocConfig config's map: an option its maker does not take, or a value its own checks
        refuse (a planner's horizon of 0, a degenerate power). The policy is built as it would be
        for the work, with a capture-time client that is never asked (building asks no
        statistics), so its own checks decide, before any work. Kinds other than checked_kinds
        (a learned policy, a mixture, which read run folders) are left to their first use."""
        from farm.core.errors import SwarmFarmError
        from farm.service.client import CaptureTimeClient

        entry = self.entry(name, field)
        if entry.kind not in self.checked_kinds:
            return
        allowed = entry.options()
        for option in options:
            if option not in allowed:
                raise ConfigError(f"{field}: {name} has no option {option!r} (options: {', '.join(allowed) or 'none'})",
                                  field=field)
        client = CaptureTimeClient(config.game_settings(), backend=_Unasked())
        try:
            entry.build(config, client, options)
        except (SwarmFarmError, TypeError, ValueError) as e:
            problem = getattr(e, "problem", None) or str(e)
            raise ConfigError(f"{field}: {problem.removeprefix(f'{name}: ')}", field=field) from None


ALLOCATORS = Registry("allocator", ("baseline", "planner", "learned", "mixture"), field="policy", client="always",
                      checked_kinds=("baseline", "planner"))
INTRUDERS = Registry("intruder policy", ("law", "heuristic", "learned", "mixture", "search"), field="intruders",
                     client="if_taken", options_field="intruder_options")
