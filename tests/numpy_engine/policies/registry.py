"""Name -> policy function maps for pursuers and evaders."""

from __future__ import annotations

from typing import Callable

import numpy as np

from workers.errors import InputError

PolicyFn = Callable[["StepContext"], np.ndarray]  # noqa: F821

PURSUER_POLICIES: dict[str, PolicyFn] = {}
EVADER_POLICIES: dict[str, PolicyFn] = {}


def pursuer_policy(name: str):
    def register(fn: PolicyFn) -> PolicyFn:
        PURSUER_POLICIES[name] = fn
        return fn

    return register


def evader_policy(name: str):
    def register(fn: PolicyFn) -> PolicyFn:
        EVADER_POLICIES[name] = fn
        return fn

    return register


def _lookup(table: dict[str, PolicyFn], name, field: str) -> PolicyFn:
    if not isinstance(name, str) or name not in table:
        raise InputError(f"{field}: unknown policy {name!r} (choose from {', '.join(sorted(table))})")
    return table[name]


def get_pursuer_policy(name: str) -> PolicyFn:
    return _lookup(PURSUER_POLICIES, name, "pursuer_policy")


def get_evader_policy(name: str) -> PolicyFn:
    return _lookup(EVADER_POLICIES, name, "evader_policy")
