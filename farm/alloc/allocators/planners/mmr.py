"""The `mmr` planner (MaxMarginalReturn): greedy maximum marginal return for one step."""

from __future__ import annotations

import numpy as np

from farm.alloc.allocators.planners.core import _TINY, _Planner, _positive_number
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.model import advance_intruders, team_sizes
from farm.core.errors import ConfigError

__all__ = ["MaxMarginalReturn"]


class MaxMarginalReturn(_Planner):
    """Greedy maximum marginal return for one step (den Broeder et al. 1959).

    The targets are the cells the intruders will hold after this step's advance
    (advance_intruders: known), with intruder masses I'_t and games of n_e_t intruders.
    Defenders within one move of a target may go there, and a target's count plays the
    game of its level (levels()). Greedy, from nothing assigned: for every target and
    every level above its current one that the free mass within reach can fill, the
    return per defender is I'_t (removed(level) - removed(current)) / (the defenders the
    level needs, in whole chunks); the best (target, level) is taken, its defenders
    drawn from the reachable cells that reach the fewest targets first, then the lowest
    cell; until no step returns anything. Ties go to the lower target, then the lower
    level. Stepping straight to any higher level, not only to the next, is what keeps
    greedy from stalling where the curve is flat: under the lattice one more defender
    often changes no game, and against many intruders small teams may catch nobody. On
    a concave curve the best step is the next level, the classic marginal rule. Mass
    with no return moves as Intercept would, towards the coming intruders, landing on a
    target only where that does not lower the target's expected eliminated mass.

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings();
    chunk: the unit of assigned mass in defenders (default 1; a finer unit such as 0.1
    lets a count that rounds up to a game be used, e.g. 4.6 defenders playing the
    6-defender game under the lattice; at most n_defenders, or no chunk could ever be
    assigned); ties: Intercept's, for the mass with no return;
    estimates: take the service's interpolation of a pair not yet computed (default
    False). A bad value, a missing client or an unknown option is a ConfigError naming it.
    """

    name = "mmr"

    def __init__(self, config: AllocConfig, client=None, *, chunk: float = 1.0, ties: str = "split",
                 estimates: bool = False, **unknown):
        super().__init__(config, client, unknown, ties)
        self.chunk = _positive_number("mmr", "chunk", chunk)
        if self.chunk > config.n_defenders:
            raise ConfigError(f"mmr: chunk {self.chunk:g} is more than the {config.n_defenders} defenders there "
                              f"are: no level could ever be filled (it would act as intercept)")
        self.plan_on_rates(estimates)

    def probabilities(self, D, I):
        """The greedy assignment's move probabilities (see the class)."""
        cfg, L = self.config, self.levels
        x = D * cfg.n_defenders
        I1, _ = advance_intruders(I, self.n, cfg.vertical_drift)
        targets = np.flatnonzero(I1 > cfg.engage_min_mass)
        sources = np.flatnonzero(x > _TINY)
        flows = np.zeros(len(self.src))
        if len(targets) == 0 or len(sources) == 0:
            return self.place(x, flows, I, lambda s, d, a: True)
        n_e = team_sizes(cfg, np.zeros(len(targets)), I1[targets])[1]
        value = np.hstack([np.zeros((len(targets), 1)), I1[targets][:, None] * self.rates.grid(L.sizes, n_e)[0]])
        reach = self.cheb[np.ix_(targets, sources)] <= 1  # (T, S)
        order = np.lexsort((sources, reach.sum(axis=0)))  # the least flexible sources first
        free = x[sources].copy()
        count = np.zeros(len(targets))
        level = np.zeros(len(targets), dtype=np.int64)
        while True:
            best, pick = 0.0, None
            for t in range(len(targets)):
                avail = free[reach[t]].sum()
                for i in range(level[t], len(L.sizes)):
                    need = L.needed(i, self.chunk, count[t])
                    if need > avail + 1e-9:
                        break
                    ratio = (value[t, i + 1] - value[t, level[t]]) / need
                    if ratio > best * (1 + 1e-12) + 1e-15:
                        best, pick = ratio, (t, i, need)
            if pick is None:
                break
            t, i, need = pick
            for j in order:
                if need <= 1e-12:
                    break
                if reach[t, j] and free[j] > 0:
                    take = min(free[j], need)
                    free[j] -= take
                    need -= take
                    count[t] += take
                    flows[self.move_index(sources[j], targets[t])] += take
            level[t] = i + 1
        where = {int(t): k for k, t in enumerate(targets)}

        def keep(s, d, amount):
            t = where.get(d)
            if t is None:
                return True
            if value[t, L.of([count[t] + amount])[0]] < value[t, L.of([count[t]])[0]] - 1e-15:
                return False
            count[t] += amount
            return True

        return self.place(x, flows, I, keep)
