"""Pursuer: head at full speed for the nearest live evader (paper eqs. 9-10)."""

from numba import njit

from workers.policies.context import unit_velocity

NEEDS_CELLS = False


@njit(cache=True, inline="always")
def pure_pursuit(j, s):
    """Pursuer j's velocity to the nearest live evader (ties: the lowest index)."""
    best, chosen = s.d2[j, 0], 0
    for i in range(1, s.d2.shape[1]):
        if s.d2[j, i] < best:
            best, chosen = s.d2[j, i], i
    return unit_velocity(s.E[chosen, 0], s.E[chosen, 1], s.P[j, 0], s.P[j, 1], s.vp)
