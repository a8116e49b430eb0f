"""Name -> policy maps for pursuers and evaders, and the compiled dispatch.

Adding a policy: write its file (a compiled function of (agent, Step) and
NEEDS_CELLS), then list it here, in the table and in the dispatch.
"""

from __future__ import annotations

from typing import NamedTuple

from numba import njit

from workers.errors import InputError
from workers.policies import area_max, area_min, centroid, constant_area, pure_pursuit, target


class Policy(NamedTuple):
    name: str
    kind: int  # its number in the compiled dispatch
    needs_cells: bool  # reads the Step's cell fields
    fn: object  # the compiled function (agent, Step) -> (ux, uy)


def _policy(module, kind: int) -> Policy:
    name = module.__name__.rsplit(".", 1)[1]
    return Policy(name, kind, module.NEEDS_CELLS, getattr(module, name))


# The kinds are the numbers the dispatch below tests.
PURSUER_POLICIES: dict[str, Policy] = {p.name: p for p in (_policy(area_min, 0), _policy(pure_pursuit, 1))}
EVADER_POLICIES: dict[str, Policy] = {
    p.name: p for p in (_policy(centroid, 0), _policy(constant_area, 1), _policy(target, 2), _policy(area_max, 3))
}


@njit(cache=True, inline="always")
def pursuer_velocity(kind, j, s):
    if kind == 0:
        return area_min.area_min(j, s)
    return pure_pursuit.pure_pursuit(j, s)


@njit(cache=True, inline="always")
def evader_velocity(kind, i, s):
    if kind == 0:
        return centroid.centroid(i, s)
    if kind == 1:
        return constant_area.constant_area(i, s)
    if kind == 2:
        return target.target(i, s)
    return area_max.area_max(i, s)


def lookup(table: dict, name, field: str):
    """table[name]; InputError naming `field` and the choices when name is not a key."""
    if not isinstance(name, str) or name not in table:
        raise InputError(f"{field}: unknown policy {name!r} (choose from {', '.join(sorted(table))})")
    return table[name]


def get_pursuer_policy(name: str) -> Policy:
    return lookup(PURSUER_POLICIES, name, "pursuer_policy")


def get_evader_policy(name: str) -> Policy:
    return lookup(EVADER_POLICIES, name, "evader_policy")
