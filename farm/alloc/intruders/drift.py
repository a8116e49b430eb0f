"""`drift`: the intruders' fixed law, the default (docs/model.md section 5)."""

from __future__ import annotations

import numpy as np

from farm.alloc.game.model import drift_routing
from farm.alloc.intruders.base import IntruderPolicy

__all__ = ["Drift"]


class Drift(IntruderPolicy):
    """Every row but the top sends the share `vertical_drift` of its mass up-left, every row but the
    bottom the same share down-left, the rest goes straight; it ignores the defenders."""

    def routing(self, D, I):
        """The drift law's routing for each of the B episodes."""
        return drift_routing(self.n, self.config.vertical_drift, len(np.atleast_2d(I)))
