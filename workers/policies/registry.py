"""The policies of each team, numbered, and the compiled dispatch made from them.

Adding a policy is one new file and one line here:

1. write ``workers/policies/<name>.py`` holding a compiled function named ``<name>`` of
   (agent index, Step) returning that agent's velocity (ux, uy), of speed at most its team's
   (workers.policies.context), and ``NEEDS_CELLS``: whether it reads the Step's cell fields
   (the engine builds the cells only for games that need them);
2. add ``"<name>"`` at the end of PURSUERS or EVADERS below.

Nothing else: a policy's kind (the number the compiled engine is given) is its position in its
team's list, and the dispatch the engine inlines (`pursuer_velocity`, `evader_velocity`: call
policy number `kind`) is generated from the lists, with an error for a kind no policy has. Its
file is part of the kernels' cache digest by being in this folder (workers.compiled). Keep the
existing names in place, so that the existing kinds keep their numbers (others: register_policy).
"""

from __future__ import annotations

import importlib
import linecache
from functools import lru_cache
from typing import NamedTuple

from numba import njit

from workers.errors import InputError, shown

__all__ = [
    "PURSUERS",
    "EVADERS",
    "Policy",
    "PURSUER_POLICIES",
    "EVADER_POLICIES",
    "lookup",
    "get_pursuer_policy",
    "get_evader_policy",
    "get_policy",
    "register_policy",
    "unregister_policy",
    "dispatch_source",
    "dispatch",
    "is_builtin",
    "pursuer_velocity",
    "evader_velocity",
]

# The built-in policies of each team: module workers.policies.<name>, kind = position.
PURSUERS = ("area_min", "pure_pursuit")
EVADERS = ("centroid", "constant_area", "target", "area_max")


class Policy(NamedTuple):
    """One policy of a team, as the engine uses it.

    name: what configs call it; kind: its number in the compiled dispatch; needs_cells:
    it reads the Step's cell fields; fn: the compiled function (agent, Step) -> (ux, uy)."""

    name: str
    kind: int
    needs_cells: bool
    fn: object


def _builtin(names: tuple[str, ...]) -> dict[str, Policy]:
    table = {}
    for kind, name in enumerate(names):
        module = importlib.import_module(f"workers.policies.{name}")
        table[name] = Policy(name, kind, module.NEEDS_CELLS, getattr(module, name))
    return table


PURSUER_POLICIES: dict[str, Policy] = _builtin(PURSUERS)
EVADER_POLICIES: dict[str, Policy] = _builtin(EVADERS)
_TABLES = {"pursuer": PURSUER_POLICIES, "evader": EVADER_POLICIES}
_BUILTIN = {"pursuer": PURSUERS, "evader": EVADERS}


def _table(team: str) -> dict[str, Policy]:
    if team not in _TABLES:
        raise InputError(f"team: must be 'pursuer' or 'evader', got {team!r}", field="team")
    return _TABLES[team]


def lookup(table: dict, name, field: str):
    """table[name]; InputError naming `field` and the choices when name is not a key."""
    if not isinstance(name, str) or name not in table:
        raise InputError(f"{field}: unknown policy {shown(name)} (choose from {', '.join(sorted(table))})", field=field)
    return table[name]


def get_policy(team: str, name: str) -> Policy:
    """The Policy called `name` of team 'pursuer' or 'evader'.

    InputError naming the field (pursuer_policy, evader_policy) when there is none."""
    return lookup(_table(team), name, f"{team}_policy")


def get_pursuer_policy(name: str) -> Policy:
    """The pursuers' Policy called `name`; InputError naming pursuer_policy when there is none."""
    return get_policy("pursuer", name)


def get_evader_policy(name: str) -> Policy:
    """The evaders' Policy called `name`; InputError naming evader_policy when there is none."""
    return get_policy("evader", name)


def register_policy(team: str, fn, *, needs_cells: bool, name: str | None = None) -> Policy:
    """Add a policy defined outside this package to team 'pursuer' or 'evader'; returns its Policy.

    fn: a numba-compiled function (agent index, Step) -> (ux, uy), as the built-ins
    (its __name__ is the policy's name unless `name` is given); needs_cells: whether it
    reads the Step's cell fields. Its kind is the next number. Every function that takes
    a policy name (simulate_games, Case, ...) then accepts it.

    The compiled kernels hold the built-in dispatch, inlined, so games that use such a
    policy are played by fresh copies of the engine's kernels compiled for the registry as
    it then is (not cached on disk: compiled once per process, in tens of seconds); games of
    built-in policies keep the cached kernels, and their numbers.
    """
    table = _table(team)
    name = getattr(fn, "__name__", None) if name is None else name
    if not isinstance(name, str) or not name:
        raise InputError(f"{team}_policy: a policy needs a name, got {name!r}")
    if name in table:
        raise InputError(f"{team}_policy: {name!r} is already a policy")
    if not hasattr(fn, "py_func"):
        raise InputError(f"{team}_policy: {name!r} must be a numba-compiled function (numba.njit)")
    policy = Policy(name, len(table), bool(needs_cells), fn)
    table[name] = policy
    return policy


def unregister_policy(team: str, name: str) -> None:
    """Remove the policy last added by register_policy to team 'pursuer' or 'evader'.

    Only the last, so that the kinds stay 0..k-1: InputError for any other policy, the
    built-ins included."""
    table = _table(team)
    last = max(table.values(), key=lambda p: p.kind)
    if name != last.name or last.kind < len(_BUILTIN[team]):
        raise InputError(f"{team}_policy: only the last registered policy can be removed, not {name!r}")
    del table[name]


def dispatch_source(team: str, n_policies: int) -> str:
    """The Python source of the dispatch over the n_policies policies of a team.

    ``<team>_velocity(kind, agent, s)`` returns ``policy_<kind>(agent, s)``, one branch per
    kind in order, and raises ValueError for any other kind."""
    lines = [f"def {team}_velocity(kind, agent, s):"]
    for kind in range(n_policies):
        lines += [f"    if kind == {kind}:", f"        return policy_{kind}(agent, s)"]
    lines.append(f"    raise ValueError('unknown {team} policy kind: not one of workers.policies.registry')")
    return "\n".join(lines) + "\n"


@lru_cache(maxsize=None)
def _compiled_dispatch(team: str, fns: tuple):
    source = dispatch_source(team, len(fns))
    filename = f"<workers.policies.registry: {team} dispatch of {len(fns)}>"
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)  # for tracebacks
    namespace = {"__name__": __name__, **{f"policy_{kind}": fn for kind, fn in enumerate(fns)}}
    exec(compile(source, filename, "exec"), namespace)
    # Not cached on its own (it has no file): it is only ever inlined into the engine's kernels.
    return njit(inline="always")(namespace[f"{team}_velocity"])


def dispatch(team: str):
    """The compiled dispatch of a team's policies as registered now.

    A function (kind, agent, Step) -> (ux, uy) for inlining into compiled code (see
    dispatch_source); the same object while the registry is unchanged."""
    fns = tuple(p.fn for p in sorted(_table(team).values(), key=lambda p: p.kind))
    return _compiled_dispatch(team, fns)


def is_builtin(policy: Policy, team: str) -> bool:
    """Whether a policy is one of its team's built-ins (in PURSUERS or EVADERS)."""
    return policy.kind < len(_BUILTIN[team])


# The built-in dispatch, inlined into the cached kernels.
pursuer_velocity = dispatch("pursuer")
evader_velocity = dispatch("evader")
