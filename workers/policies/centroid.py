"""Evader: move to the centroid of its own Voronoi cell (paper eq. 12)."""

from numba import njit

from workers.policies.context import unit_velocity

NEEDS_CELLS = True


@njit(cache=True, inline="always")
def centroid(i, s):
    """Evader i's velocity to the centroid of its cell."""
    return unit_velocity(s.cen[i, 0], s.cen[i, 1], s.E[i, 0], s.E[i, 1], s.ve)
