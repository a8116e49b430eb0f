"""Evader: ascend its cell's area gradient (beyond the paper).

u ~ sum_j (L_j / |x_p^j - x_e|) (C_bj - x_e) over neighbouring pursuers j, the
negative of the pursuers' pull of eq. 7; with no pursuer neighbour, move to the
centroid.
"""

import math

from numba import njit

from workers.policies.centroid import centroid
from workers.policies.context import unit_velocity

NEEDS_CELLS = True


@njit(cache=True, inline="always")
def area_max(i, s):
    """Evader i's velocity up its cell's area gradient (the module doc), or to its centroid."""
    if s.nb_start[i + 1] == s.nb_start[i]:
        return centroid(i, s)
    ex, ey = s.E[i, 0], s.E[i, 1]
    wx, wy = 0.0, 0.0
    for t in range(s.nb_start[i], s.nb_start[i + 1]):
        j = s.nb_j[t]
        weight = s.nb_len[t] / math.hypot(s.P[j, 0] - ex, s.P[j, 1] - ey)
        wx += weight * (s.nb_mid[t, 0] - ex)
        wy += weight * (s.nb_mid[t, 1] - ey)
    return unit_velocity(ex + wx, ey + wy, ex, ey, s.ve)
