"""The level repair: a learned allocator's action moved onto the games it almost plays.

Under `team_sizes: lattice` a target cell's game is a step function of its defender count
(docs/model.md section 7, "Levels"): 27.5 defenders play a 24-defender game, 27.7 play 32.
receding_horizon plans each target at the least count of the level it wants (its window's low
end, `levels().lo`, 0.1 defender inside the rounding threshold), so an allocator that imitates
it to within 1% of a cell's mass lands on the wrong side of the threshold about half the time
and plays the smaller game with the defenders of the larger. LevelRepair moves such a count
over the threshold, from defenders that play no game or have some to spare; Repaired and
RepairedActions put it behind a learned allocator and a gymnasium env. What it changes in the
learners' returns, and its cost a step: docs/results.md, "The level repair".
"""

from __future__ import annotations

import bisect

import gymnasium
import numpy as np

from farm.alloc.allocators.planners.core import action_from_probabilities, levels
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import Layout, move_probabilities
from farm.alloc.game.model import advance_intruders, team_sizes
from farm.core.errors import ConfigError

__all__ = ["REPAIRS", "LevelRepair", "Repaired", "RepairedActions", "check_repair", "repaired"]

REPAIRS = ("none", "levels")  # a learned allocator's output: its network's action, or that action repaired
TOL = 0.5  # defenders: the repair fills a gap to the next level's window of up to this many,
REL = 0.15  # ... or up to this share of that window's low end, when that is more


def check_repair(value, field: str = "repair") -> str:
    """value if it is one of REPAIRS, else ConfigError (one line naming field)."""
    if not isinstance(value, str) or value not in REPAIRS:
        raise ConfigError(f"{field}: must be one of {', '.join(REPAIRS)}, got {value!r}", field=field)
    return value


class LevelRepair:
    """The level repair of a config's actions: LevelRepair(config)(obs, action) -> action.

    With the action's move probabilities p (the env's own map,
    farm.alloc.game.dynamics.move_probabilities) the defenders' flows along each move are
    f = p D[src] n_defenders, and each cell's count after the move is x = the inflow. The
    targets are the cells that hold intruders after their advance (the env's own advance). For
    each target, the most intruder mass first, whose count lies within `tol` below the low end
    of the next level's window, lo - x <= max(tol, rel lo), the defect is filled from free
    defenders of the target's neighbours (the cells with a move into it): those whose move goes
    to a cell that is no target, or that plays no game, or to a target above its own window's
    low end (the surplus beyond it), in move order. A target is filled whole or not at all:
    when the free defenders are short, nothing moves. The new flows are turned back into the
    action with the planners' own action_from_probabilities.

    Why it is right (and what it does not do). It moves defenders only along feasible moves of
    their own cell, so every source keeps its mass (each cell's slice of probabilities sums to
    1) and the realised action is a legal one; it never takes a defender from a target below
    its window's low end, so no game it did not aim at gets smaller, and a target it fills
    plays the next level's game (the window's margin absorbs the softmax's leak, as for the
    planners). It never raises a count by more than the tolerance, so the learner's choice of
    targets and levels stands: the repair only decides the side of a threshold the learner came
    within a tolerance of. It knows the config (levels, advance) and nothing of the
    capture-time statistics. With no target near a threshold it returns an action whose move
    probabilities equal the learner's (to the softmax's floor of exp(-2 beta) p_max on unwanted
    moves).

    Cost: the counts and the targets near a threshold are found with numpy; the fill is a loop
    in Python over those targets only (on Python floats: the same float64 arithmetic, faster
    than numpy scalars) and their neighbours' moves. tests/test_repair.py checks it equals the
    plain loop over every target; benchmarks/learners.py and benchmarks/theatre.py time it.

    config: AllocConfig; tol: defenders, rel: a share of the next window's low end (the gap
    filled is at most max(tol, rel lo)).
    """

    def __init__(self, config: AllocConfig, tol: float = TOL, rel: float = REL):
        self.config, self.tol, self.rel = config, float(tol), float(rel)
        self.layout = Layout(config.grid_size)
        self.levels = levels(config)
        L = self.layout
        src, dst = L.src.tolist(), L.dst.tolist()
        moves_of = [list(range(a, a + n)) for a, n in zip(L.start.tolist(), L.n_moves.tolist())]
        # For each cell d, its feeds: (m_in, [(m, e), ...]) for every move m_in into d, with the
        # other moves m of m_in's source cell and where they go (e != d), in move order.
        self.feeds = [[(m_in, [(m, dst[m]) for m in moves_of[src[m_in]] if dst[m] != d])
                       for m_in in np.flatnonzero(L.dst == d).tolist()] for d in range(L.cells)]
        self.leak = 8.0 * np.exp(-2.0 * config.softmax_beta) if config.action_map == "softmax" else 0.0

    def floors(self, x: np.ndarray) -> np.ndarray:
        """The least count that plays the game each count x plays, inside its window: x: (k,)
        float64 -> (k,) float64 (x itself where that window's low end is above x, a count just
        past a rounding threshold, with nothing to spare; 0.0 for a count that plays no game)."""
        x = np.asarray(x, dtype=np.float64)
        n_p, _ = team_sizes(self.config, x / self.config.n_defenders, np.ones_like(x))
        if self.config.team_sizes == "lattice":
            low = self.levels.lo[np.minimum(np.searchsorted(self.levels.sizes, n_p), len(self.levels.lo) - 1)]
        else:
            low = n_p - 0.4 + self.leak * n_p
        return np.where(n_p == 0, 0.0, np.minimum(x, low))

    def flows(self, obs: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, ...]:
        """(p: (A,) float64 the action's move probabilities, f: (A,) float64 the defenders along
        each move, x: (N^2,) float64 each cell's count after the move, target: (N^2,) bool the
        cells holding intruders after their advance, I2: (N^2,) float64 that mass) of obs:
        (2 N^2,) [D, I] and action: (A,)."""
        c, L = self.config, self.layout
        k = L.cells
        obs = np.asarray(obs, dtype=np.float64)
        D, I = np.maximum(obs[:k], 0.0), np.maximum(obs[k:], 0.0)
        p = move_probabilities(L, c, np.asarray(action, dtype=np.float64).reshape(1, -1))[0]
        f = p * D[L.src] * c.n_defenders
        I2, _ = advance_intruders(I, L.n, c.vertical_drift)
        x = np.bincount(L.dst, weights=f, minlength=k)
        return p, f, x, I2 > c.engage_min_mass, I2

    def _takes(self, d: int, need: float, f: list, free: list) -> list | None:
        """The defenders that fill target d's gap of `need`: [(m, e, m_in, amount), ...], each
        taken from move m (to cell e, not d) of the source of a move m_in into d, in the order of
        self.feeds[d], at most f[m] and e's free count free[e] (taken off free). None, with free
        as it was, when all of them fall short of need."""
        takes, got = [], 0.0
        for m_in, outs in self.feeds[d]:
            for m, e in outs:
                if f[m] <= 0.0:
                    continue
                amount = min(f[m], free[e], need - got)
                if amount > 0.0:
                    takes.append((m, e, m_in, amount))
                    free[e] -= amount
                    got += amount
                if got >= need:
                    break
            if got >= need:
                break
        if got < need:
            for _, e, _, amount in takes:
                free[e] += amount
            return None
        return takes

    def __call__(self, obs, action) -> np.ndarray:
        """The repaired action: obs (2 N^2,) [D, I], action (A,) -> (A,) float32 in [-1, 1]."""
        L, lo = self.layout, self.levels.lo
        p, f, x, target, I2 = self.flows(obs, action)
        free = np.where(target, x - self.floors(x), x)  # what each cell's count can give without a smaller game
        top = len(lo)
        above = np.searchsorted(lo, x, side="right")
        nxt = lo[np.minimum(above, top - 1)]  # the next window's low end (the top one's past it)
        near = target & (above < top) & (nxt - x + 1e-9 <= np.maximum(self.tol, self.rel * nxt))
        order = np.argsort(-I2, kind="stable")
        order = order[: int(np.count_nonzero(target))].tolist()  # the targets, the most intruder mass first
        # A target is looked at when it starts near a threshold, or (only in round-off) after it gave
        # defenders: a count only falls before its own turn, and falling moves it away from the
        # next window except when it lands a rounding error below its own window's low end.
        look = near.tolist()
        rank = np.empty(L.cells, dtype=np.int64)
        rank[order] = np.arange(len(order))
        rank = rank.tolist()
        lo_list, tol, rel = lo.tolist(), self.tol, self.rel
        f, x, free, target = f.tolist(), x.tolist(), free.tolist(), target.tolist()
        changed = False
        for r, d in enumerate(order):
            if not look[d]:
                continue
            i = bisect.bisect_right(lo_list, x[d])
            if i >= top:
                continue
            need = lo_list[i] - x[d] + 1e-9
            if need > max(tol, rel * lo_list[i]):
                continue
            takes = self._takes(d, need, f, free)
            if takes is None:  # not filled whole: nothing moves
                continue
            for m, e, m_in, amount in takes:
                f[m] -= amount
                x[e] -= amount
                f[m_in] += amount
                x[d] += amount
                if target[e] and rank[e] > r:
                    look[e] = True
            free[d] = 0.0  # at its new window's low end
            changed = True
        if not changed:
            return np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0).astype(np.float32)
        f = np.asarray(f)
        total = np.add.reduceat(f, L.start)[L.src]
        q = np.where(total > 0.0, f / np.where(total > 0.0, total, 1.0), p)
        return action_from_probabilities(self.config, q, L.start, L.src)


class Repaired:
    """An allocator whose actions go through a LevelRepair: policy (predict() as SB3's) and config."""

    def __init__(self, policy, config: AllocConfig):
        self.policy, self.repair = policy, LevelRepair(config)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The policy's action for obs, repaired (LevelRepair), and its state."""
        action, state = self.policy.predict(obs, state, episode_start, deterministic)
        return self.repair(np.asarray(obs), np.asarray(action).reshape(-1)), state


def repaired(policy, config: AllocConfig, repair: str):
    """policy as it is (`none`) or its actions repaired (`levels`) for config's map."""
    return Repaired(policy, config) if check_repair(repair) == "levels" else policy



class RepairedActions(gymnasium.Wrapper):
    """A single allocation env (SwarmAllocationEnv) whose actions are repaired (LevelRepair)
    against the observation it last returned: training's periodic evaluations of a run with
    `repair: levels` play so, as the trained allocator acts afterwards."""

    def __init__(self, env):
        super().__init__(env)
        self.repair = LevelRepair(env.unwrapped.config)
        self.last_obs = None

    def reset(self, **kwargs):
        """The env's reset; its observation kept for the next step's repair."""
        obs, info = self.env.reset(**kwargs)
        self.last_obs = obs
        return obs, info

    def step(self, action):
        """The env's step with the action repaired against the last observation."""
        obs, reward, terminated, truncated, info = self.env.step(self.repair(self.last_obs, action))
        self.last_obs = obs
        return obs, reward, terminated, truncated, info
