"""Evader: head for a fixed target point (default (0, 5), the defenders' side).

The last step lands exactly on the target (speed min(v, distance/dt)) and the
evader stays there: unit steps would otherwise oscillate around it.
"""

import math

from numba import njit

NEEDS_CELLS = False
ARRIVED = 1e-9


@njit(cache=True, inline="always")
def target(i, s):
    """Evader i's velocity to the target point, landing on it on the last step."""
    hx, hy = s.target[0] - s.E[i, 0], s.target[1] - s.E[i, 1]
    dist = math.hypot(hx, hy)
    if dist <= ARRIVED:
        return 0.0, 0.0
    scale = min(s.ve, dist / s.dt) / dist
    return hx * scale, hy * scale
