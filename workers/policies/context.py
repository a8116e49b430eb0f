"""What a policy sees of one game at one step, and the unit-heading helper.

A policy is a small compiled function of (agent index, Step) returning that
agent's velocity (ux, uy), of speed at most its team's. The engine fills the
Step once per step; the cell fields are filled only when a policy of the game
declares NEEDS_CELLS.
"""

from __future__ import annotations

import math
from collections import namedtuple

from numba import njit

HEADING_MIN = 1e-12

Step = namedtuple(
    "Step",
    [
        "P",       # (n_p, 2) float64 pursuer positions
        "E",       # (n_e, 2) float64 evader positions
        "alive",   # (n_e,) bool evaders still in the game
        "d2",      # (n_p, n_e) float64 squared pursuer-evader distances, inf for evaders out of the game
        "target",  # (2,) float64 goal of `target` evaders
        "dt",      # float64 time step
        "vp",      # float64 pursuers' speed
        "ve",      # float64 evaders' speed
        "area",    # (n_e,) float64 area of each live evader's cell
        "cen",     # (n_e, 2) float64 centroid of each live evader's cell
        "nb_start",  # (n_e + 1,) int64: evader i's pursuer neighbours are entries nb_start[i]:nb_start[i+1]
        "nb_j",    # (K,) int64 the neighbouring pursuer of each entry, in the cell's edge order
        "nb_len",  # (K,) float64 length of the shared edge (> 1e-9)
        "nb_mid",  # (K, 2) float64 its midpoint C_b
        "pn_i",    # (n_p,) int64 nearest neighbouring live evader of each pursuer (ties: lowest index), -1 if none
        "pn_mid",  # (n_p, 2) float64 midpoint of the edge the pursuer shares with it
    ],
)
Step.__doc__ = """What a policy sees of one game at one step (fields commented above; the cell fields
area, cen, nb_*, pn_* are filled only for games whose policies declare NEEDS_CELLS)."""


@njit(cache=True, inline="always")
def unit_velocity(gx, gy, x, y, speed):
    """Velocity of the given speed from (x, y) towards (gx, gy); zero when closer than 1e-12."""
    hx, hy = gx - x, gy - y
    norm = math.hypot(hx, hy)
    if norm >= HEADING_MIN:
        scale = speed / norm
        return hx * scale, hy * scale
    return 0.0, 0.0
