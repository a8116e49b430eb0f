"""`split_away`: each cell's mass splits away from the largest defender mass in front of it."""

from __future__ import annotations

import numpy as np

from farm.alloc.intruders.base import IntruderPolicy

__all__ = ["SplitAway"]


class SplitAway(IntruderPolicy):
    """The rule: of the cells a cell's routes land on (the column to its left), the ones holding the
    most defenders get none of its mass, which splits evenly over its other routes; when every
    landing cell holds as many defenders (none, say), or the cell is in column 0, it goes straight."""

    def routing(self, D, I):
        """Each cell's routes weighted 0 to its most defended landing cells and evenly over the rest."""
        D = np.atleast_2d(np.asarray(D, dtype=np.float64))
        landing, feasible = self.landing(), self.feasible()
        held = np.where(landing >= 0, D[:, np.maximum(landing, 0)], -np.inf)  # (B, N^2, 3)
        held = np.where(feasible[None], held, -np.inf)
        top = held.max(axis=2, keepdims=True)
        low = np.where(feasible[None], held, np.inf).min(axis=2, keepdims=True)
        spread = (top > low) & np.isfinite(top)  # some landing cells hold fewer defenders than others
        keep = feasible[None] & (held < top)
        share = keep / np.maximum(keep.sum(axis=2, keepdims=True), 1)
        straight = np.array([0.0, 1.0, 0.0])
        share = np.where(spread, share, straight)
        return share[:, :, 0], share[:, :, 2]
