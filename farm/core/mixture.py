"""A mixed strategy's members and weights, checked: the one rule of the allocators' and the
intruders' `mixture`."""

from __future__ import annotations

import numpy as np

from farm.core.checks import is_whole
from farm.core.errors import ConfigError

__all__ = ["DRAWS", "mixture_members", "mixture_weights", "saved_member", "saved_generator"]

DRAWS = ("episode", "step", "mean")  # a member drawn per episode or per step, or the members' mean move


def mixture_members(owner: str, members, weights, draw: str, key: str) -> tuple[list[tuple[str, dict]], np.ndarray]:
    """The checked members ((name, options) each) and weights ((m,) float64 summing to 1) of a mixture.

    members: a list of names or {key: name, options: {...}} mappings (key: "policy" for
    allocators, "intruders" for intruder policies); weights: None (uniform) or m numbers >= 0
    with a positive sum; draw: one of DRAWS. ConfigError (one line naming owner.field) otherwise.
    """
    if not isinstance(members, (list, tuple)) or not members:
        raise ConfigError(f"{owner}.members: a non-empty list of members, got {members!r}", field=f"{owner}.members")
    parsed = []
    for i, member in enumerate(members):
        if isinstance(member, str):
            member = {key: member}
        if not isinstance(member, dict) or not isinstance(member.get(key), str) \
                or not set(member) <= {key, "options"} or not isinstance(member.get("options", {}), dict):
            raise ConfigError(f"{owner}.members: member {i} is not a name or {{{key}: NAME, options: {{...}}}}: "
                              f"{member!r}", field=f"{owner}.members")
        parsed.append((member[key], dict(member.get("options", {}))))
    w = np.full(len(parsed), 1.0 / len(parsed)) if weights is None else mixture_weights(owner, weights, len(parsed))
    if draw not in DRAWS:
        raise ConfigError(f"{owner}.draw: one of {', '.join(DRAWS)}, got {draw!r}", field=f"{owner}.draw")
    return parsed, w


def mixture_weights(owner: str, weights, n: int) -> np.ndarray:
    """n weights checked and normalised: (n,) float64 summing to 1. ConfigError (one line naming
    owner.weights) unless weights is a list (or array) of n real numbers, not booleans, >= 0 whose
    sum is positive and finite."""
    if isinstance(weights, np.ndarray):
        numbers = weights.dtype.kind in "iuf"
    else:
        numbers = isinstance(weights, (list, tuple)) and all(
            isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))
            for x in weights)
    w = np.asarray(weights, dtype=np.float64) if numbers else np.array([np.nan])
    with np.errstate(over="ignore"):
        total = w.sum()
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not (np.isfinite(total) and total > 0):
        raise ConfigError(f"{owner}.weights: {n} numbers >= 0 with a positive finite sum, got {weights!r}",
                          field=f"{owner}.weights")
    return w / total


def saved_member(state: dict, n: int) -> int | None:
    """The member an episode's saved draw (a mixture episode's get_state()) plays, as an index of
    the n members; None for a draw per step. ValueError for a member that is not one."""
    if "member" not in state:
        return None
    member = state["member"]
    if not is_whole(member, numpy=True) or not 0 <= member < n:
        raise ValueError(f"member: {member!r} is not one of the {n} members")
    return int(member)


def saved_generator(state: dict) -> np.random.Generator:
    """The generator of an episode's saved draw per step (its get_state()'s `rng`)."""
    rng = np.random.default_rng()
    rng.bit_generator.state = state["rng"]
    return rng
