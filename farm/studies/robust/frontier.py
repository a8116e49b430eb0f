"""The drift case against the worst case over a meta-game's allocators: for each margin, the
mixture keeping at least the reference allocator's drift payoff less that margin with the best
guaranteed value (farm.core.matrix_game's floor), beside each allocator alone."""

from __future__ import annotations

import numpy as np

from farm.core.matrix_game import solve

__all__ = ["drift_frontier", "pure_points"]


def drift_frontier(M, reference: int, column: int, margins) -> list[dict]:
    """The floored mixtures of the payoff matrix M: (m, n) float64 (allocators by row), a margin
    each: [{"margin", "target": M[reference, column] - margin, "drift": the mixture's payoff
    against column, "worst": its least payoff over the columns (the value under the floor),
    "weights": (m,) list}], margins in the order given."""
    M = np.asarray(M, dtype=np.float64)
    out = []
    for margin in margins:
        target = float(M[reference, column]) - float(margin)
        s = solve(M, (column, target))
        out.append({"margin": float(margin), "target": target, "drift": float(s.row @ M[:, column]),
                    "worst": float((s.row @ M).min()), "weights": s.row.tolist()})
    return out


def pure_points(M, column: int) -> list[tuple[float, float]]:
    """Each allocator alone: (its payoff against column, its least payoff over the columns), by row."""
    M = np.asarray(M, dtype=np.float64)
    return [(float(row[column]), float(row.min())) for row in M]
