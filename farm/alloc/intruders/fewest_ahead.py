"""`fewest_ahead`: each cell's mass turns toward the neighbouring row with the fewest defenders ahead."""

from __future__ import annotations

import numpy as np

from farm.alloc.intruders.base import IntruderPolicy, ahead_of, choose

__all__ = ["FewestAhead"]


class FewestAhead(IntruderPolicy):
    """The rule: each cell's whole mass takes the route (up-left, left, down-left) into the row
    whose defenders ahead, in the columns left of the cell, are fewest; ties go straight, then
    up, then down."""

    def routing(self, D, I):
        """Each cell's cheapest route by the defenders ahead in the row it turns into."""
        ahead = ahead_of(D, self.n)  # (B, N, N)
        rr = np.clip(self.rows[:, None] + np.array([-1, 0, 1])[None, :], 0, self.n - 1)  # (N^2, 3)
        cost = ahead[:, rr, self.cols[:, None]]  # (B, N^2, 3)
        return choose(cost, self.feasible())
