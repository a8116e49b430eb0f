"""Name -> policy function maps for pursuers and evaders."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from workers.policies.registry import lookup

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


def get_policy(side: str, name: str) -> PolicyFn:
    """side 'pursuer' or 'evader'."""
    return lookup(PURSUER_POLICIES if side == "pursuer" else EVADER_POLICIES, name, f"{side}_policy")


def get_pursuer_policy(name: str) -> PolicyFn:
    return get_policy("pursuer", name)


def get_evader_policy(name: str) -> PolicyFn:
    return get_policy("evader", name)
