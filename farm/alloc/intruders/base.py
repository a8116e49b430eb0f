"""What every intruder policy builds on: the map's layout and the routing's arrays."""

from __future__ import annotations

import numpy as np

from farm.alloc.game.dynamics import Layout

__all__ = ["IntruderPolicy", "ahead_of", "choose"]

# the order in which ties between a cell's routes are broken: straight first, then up, then down
_TIE_ORDER = np.array([1, 0, 2])  # positions of d_row 0, -1, +1 in (-1, 0, +1)


class IntruderPolicy:
    """The shared part of the intruder policies: config (the map's AllocConfig), its layout
    (farm.alloc.game.dynamics.Layout), n the grid side, and rows, cols: (N^2,) int64 each cell's
    row and column. A policy answers routing(D, I) (the registry's module doc)."""

    def __init__(self, config):
        self.config = config
        self.n = config.grid_size
        self.layout = Layout(self.n)
        self.rows, self.cols = np.divmod(np.arange(self.n * self.n), self.n)

    @classmethod
    def make(cls, config):
        """The registry's maker: the policy for config's map."""
        return cls(config)

    def routing(self, D: np.ndarray, I: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(up, down): (B, N^2) float64 each, from the defenders D and intruders I it sees ((B, N^2) float64)."""
        raise NotImplementedError

    def landing(self) -> np.ndarray:
        """(N^2, 3) int64: the cell each route of each cell lands on (up-left, left, down-left), -1 for
        a route off the grid's rows or from column 0 (whose mass leaves whatever its route)."""
        n, r, c = self.n, self.rows[:, None], self.cols[:, None]
        rr = r + np.array([-1, 0, 1])[None, :]
        ok = (rr >= 0) & (rr < n) & (c >= 1)
        return np.where(ok, rr * n + (c - 1), -1)

    def feasible(self) -> np.ndarray:
        """(N^2, 3) bool: the routes each cell has (not up-left from the top row, not down-left from the bottom)."""
        rr = self.rows[:, None] + np.array([-1, 0, 1])[None, :]
        return (rr >= 0) & (rr < self.n)


def ahead_of(D: np.ndarray, n: int) -> np.ndarray:
    """The defenders ahead of each cell's intruders, row by row: D: (B, N^2) float64 -> (B, N, N)
    float64, [b, r, c] the defenders of row r in the columns left of c (those still to cross)."""
    grid = np.asarray(D, dtype=np.float64).reshape(-1, n, n)
    ahead = np.zeros_like(grid)
    ahead[:, :, 1:] = np.cumsum(grid[:, :, :-1], axis=2)
    return ahead


def choose(cost: np.ndarray, feasible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's mass sent whole along its cheapest route: cost: (B, N^2, 3) float64 per route
    (up-left, left, down-left), feasible: (N^2, 3) bool -> (up, down): (B, N^2) float64 of 0s and
    1s. Ties go straight, then up, then down."""
    cost = np.where(feasible[None], cost, np.inf)
    best = _TIE_ORDER[np.argmin(cost[:, :, _TIE_ORDER], axis=2)]  # 0: up, 1: straight, 2: down
    return (best == 0).astype(np.float64), (best == 2).astype(np.float64)
