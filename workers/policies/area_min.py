"""Pursuer: area minimization (paper Alg. 1, eqs. 7-8).

A pursuer that neighbours live evaders heads for the midpoint C_b of the edge it
shares with the nearest of them; any other pursuer uses pure pursuit.
"""

from numba import njit

from workers.policies.context import unit_velocity
from workers.policies.pure_pursuit import pure_pursuit

NEEDS_CELLS = True


@njit(cache=True, inline="always")
def area_min(j, s):
    """Pursuer j's velocity to the midpoint of the edge shared with its nearest neighbouring evader."""
    if s.pn_i[j] < 0:
        return pure_pursuit(j, s)
    return unit_velocity(s.pn_mid[j, 0], s.pn_mid[j, 1], s.P[j, 0], s.P[j, 1], s.vp)
