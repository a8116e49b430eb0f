"""`least_defended`: all the mass converges on the row with the fewest defenders ahead."""

from __future__ import annotations

import numpy as np

from farm.alloc.intruders.base import IntruderPolicy, ahead_of, choose

__all__ = ["LeastDefended"]


class LeastDefended(IntruderPolicy):
    """The rule: each cell's mass heads for the row, among all rows, with the fewest defenders ahead
    of it (in the columns left of the cell; ties to the nearest row, then the upper), moving one
    row toward it each step (straight once on it)."""

    def routing(self, D, I):
        """Each cell's route one row toward its least-defended row."""
        n = self.n
        ahead = ahead_of(D, n)[:, :, self.cols]  # (B, N rows, N^2 cells): row t's defenders ahead of each cell
        distance = np.abs(np.arange(n)[:, None] - self.rows[None, :])  # (N, N^2)
        # lexicographic: fewest ahead, then nearest, then upper (argmin takes the first)
        key = ahead * (n + 1) ** 2 + distance[None] * (n + 1) + np.arange(n)[None, :, None]
        exact = ahead == ahead.min(axis=1, keepdims=True)
        target = np.argmin(np.where(exact, key, np.inf), axis=1)  # (B, N^2)
        step = np.sign(target - self.rows[None, :])  # -1 up, 0 straight, +1 down
        cost = np.abs(np.array([-1, 0, 1])[None, None, :] - step[:, :, None]).astype(np.float64)
        return choose(cost, self.feasible())
