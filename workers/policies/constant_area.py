"""Evader: keep the cell's area constant (paper eq. 11).

Head for C_b of the edge shared with the nearest neighbouring pursuer (ties: the
lowest index); with no pursuer neighbour, move to the centroid.
"""

import numpy as np
from numba import njit

from workers.policies.centroid import centroid
from workers.policies.context import unit_velocity

NEEDS_CELLS = True


@njit(cache=True, inline="always")
def constant_area(i, s):
    """Evader i's velocity to the edge midpoint shared with its nearest neighbouring pursuer."""
    best, best_j, chosen = np.inf, -1, -1
    for t in range(s.nb_start[i], s.nb_start[i + 1]):
        j = s.nb_j[t]
        d = s.d2[j, i]
        if d < best or (d == best and j < best_j):
            best, best_j, chosen = d, j, t
    if chosen < 0:
        return centroid(i, s)
    return unit_velocity(s.nb_mid[chosen, 0], s.nb_mid[chosen, 1], s.E[i, 0], s.E[i, 1], s.ve)
