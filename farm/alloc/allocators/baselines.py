"""The baselines: hand-written allocators behind the same interface as a trained SB3 model:
`predict(obs, deterministic=True) -> (action, None)`.

Each builds the wanted move probabilities per cell and returns the action whose
`softmax` (beta = 5) or `shifted` map reproduces them as closely as [-1, 1] allows.
"""

from __future__ import annotations

import numpy as np

from farm.alloc.game.dynamics import moves


class _Allocator:
    """The shared part of the baselines: the grid's moves and the SB3-style predict().

    grid_size: the grid side N. src_rc, dst_rc: (A, 2) int64 the (row, col) of each
    move's source and destination cell, in the action's order (moves(N)).
    """

    def __init__(self, grid_size: int):
        self.n = grid_size
        self.src, self.dst, self.start = moves(grid_size)
        self.src_rc = np.stack(divmod(self.src, grid_size), axis=1)
        self.dst_rc = np.stack(divmod(self.dst, grid_size), axis=1)

    @classmethod
    def make(cls, config, client=None):
        """The registry's maker (farm.alloc.allocators): the baseline for config's grid;
        a baseline asks no statistics."""
        return cls(config.grid_size)

    def preference(self, D: np.ndarray, I: np.ndarray) -> np.ndarray:
        """Score every feasible move: the higher, the more of the source cell's mass goes there.

        D, I: (N^2,) float64 the densities -> (A,) float64 scores in [-1, 1], the action.
        """
        raise NotImplementedError

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The action for an observation, as a trained SB3 model's predict method returns it.

        obs: (2 N^2,) float32 [D, I] -> (action: (A,) float32 in [-1, 1], state). state
        is passed through; episode_start and deterministic are accepted and unused (the
        baselines are deterministic).
        """
        obs = np.asarray(obs, dtype=np.float64)
        k = self.n * self.n
        action = self.preference(obs[:k], obs[k:]).astype(np.float32)
        return np.clip(action, -1.0, 1.0), state


class StayAtBase(_Allocator):
    """Everybody stays where they are (at the base)."""

    def preference(self, D, I):
        """Score 1 for staying and -1 for every move to a neighbour."""
        return np.where(self.src == self.dst, 1.0, -1.0)


class GreedyNearestIntruder(_Allocator):
    """Every cell sends its defenders one step towards the nearest intruder mass."""

    def preference(self, D, I):
        """Score 1 for the moves that bring a cell's defenders closer to its nearest intruder cell.

        The nearest in Chebyshev distance (the grid's king moves), ties going to the
        larger intruder mass; a cell already on its target stays; -1 for every other move
        (with no intruder mass left, everybody stays).
        """
        targets = np.flatnonzero(I > 1e-6)
        if len(targets) == 0:
            return np.where(self.src == self.dst, 1.0, -1.0)
        t_rc = np.stack(divmod(targets, self.n), axis=1)  # (m, 2)
        # Chebyshev distance (the grid's king moves) from each source and each destination to each target.
        d_src = np.abs(self.src_rc[:, None, :] - t_rc[None]).max(axis=2)  # (A, m)
        nearest = np.argmin(d_src + 1e-3 * (1 - I[targets])[None], axis=1)
        goal = t_rc[nearest]
        d_dst = np.abs(self.dst_rc - goal).max(axis=1)
        d_now = np.abs(self.src_rc - goal).max(axis=1)
        return np.where(d_dst < d_now, 1.0, np.where((d_dst == d_now) & (d_now == 0), 1.0, -1.0))


class SpreadEvenly(_Allocator):
    """Defenders flow towards cells holding less than an even share."""

    def preference(self, D, I):
        """Score each move to a neighbour by the destination's deficit below the even share 1/N^2.

        (share - D_dst) / share clipped to [-1, 1]; staying scores 0.
        """
        share = 1.0 / (self.n * self.n)
        deficit = np.clip((share - D[self.dst]) / share, -1.0, 1.0)
        return np.where(self.src == self.dst, 0.0, deficit)

