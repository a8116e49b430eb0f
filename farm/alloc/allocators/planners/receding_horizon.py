"""The `receding_horizon` planner (RecedingHorizon): a program over the next H steps
(scipy.optimize, HiGHS) maximising the env's own expected reward; the first step applied."""

from __future__ import annotations

import numpy as np

from farm.alloc.allocators.planners.core import MAX_PLANS, _count, _Planner, _positive_number, plan_horizon
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.model import team_sizes

__all__ = ["RecedingHorizon"]


class RecedingHorizon(_Planner):
    """Plans H steps over the known advance, maximising the env's expected reward summed over them.

    The program: a time-expanded network of the defenders' mass, nodes (k, cell) for
    steps k = 0..H, continuous flows along each step's feasible moves, the defenders now
    where the observation has them. A target is a (step, cell) the intruders will hold
    (their advance, known); its inflow chooses one level (levels(): one-hot variables,
    each level's count range enforced on the inflow). A level's value is what the env's
    reward gains from that engagement, M (c_capture s - removed g): M the cell's
    intruder mass before it, removed and s the service's frac_captured_tau and capture
    score of its game (n_e from M), g the reward per unit of intruder mass left after
    it, over the rest of the horizon (-c_distribution for every step it is still on the
    grid, -breach_penalty if it breaches, and what later engagements gain from it;
    computed backwards through the advance). The value is exact for one engagement given
    the others; M and g depend on the others (a row met twice is worth less the second
    time), so the program is solved around a nominal plan (at first: no engagements),
    the plan simulated with the env's model and the program solved again around it,
    `iterations` times; the plan whose simulated reward is best is kept, its first step
    applied, and the next call plans again.

    Solving: with H = 1 by HiGHS's branch and bound (scipy.optimize.milp) to optimality,
    the one-step optimum over the levels. With H > 1 by the LP relaxation, in
    which a target's value is the concave envelope of its levels' values, rounded by
    relax-and-fix: every target whose levels come out mixed is fixed at the highest level
    its planned inflow fills, the others may only go up, and the LP is solved again;
    after `rounds` rounds every target is fixed (a fix that leaves no feasible plan is
    undone and the target capped there instead). Why not branch and bound throughout: on
    8x8 (800 v 400) the first steps' programs have 544 level variables, and HiGHS's branch
    and bound takes seconds on each where an LP takes milliseconds; relax-and-fix comes near
    the integer optimum (docs/model.md section 7 has the timings and the gap).

    Only what can matter is in the program: nodes reachable from the defenders that can
    still reach a target; mass may leave the program only through a move to a cell
    outside it (never a target). Mass the plan does not use moves as Intercept would,
    landing on a first step's target only where that leaves its game as planned.

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings();
    horizon: int >= 1 or None (default): the steps planned; None plans until the
    intruders now on the grid have breached (the right-most column holding intruders,
    plus one); no plan goes past max_steps (the steps taken are read from that column:
    the intruders start in the right-most one); iterations: int >= 1, programs per call
    (default 2); rounds: int >= 1, relax-and-fix rounds before every target is fixed
    (default 2); ties: Intercept's, for the unused mass; estimates: take the service's
    interpolation of a pair not yet computed (default False); time_limit: seconds for a
    branch and bound (default 10; HiGHS's best plan when it runs out). A bad value, a
    missing client or an unknown option is a ConfigError naming it.

    Attribute last: the last call's dict, horizon (int), programs (int, the LPs and branch
    and bounds solved) and reward (float, the kept plan's simulated reward over the
    horizon; None without a plan).
    """

    name = "receding_horizon"

    def __init__(self, config: AllocConfig, client=None, *, horizon: int | None = None, iterations: int = 2,
                 rounds: int = 2, ties: str = "split", estimates: bool = False, time_limit: float = 10.0,
                 **unknown):
        super().__init__(config, client, unknown, ties)
        self.horizon = None if horizon is None else _count("receding_horizon", "horizon", horizon)
        self.iterations = _count("receding_horizon", "iterations", iterations, maximum=MAX_PLANS)
        self.rounds = _count("receding_horizon", "rounds", rounds, maximum=MAX_PLANS)
        self.time_limit = _positive_number("receding_horizon", "time_limit", time_limit)
        self.plan_on_rates(estimates)
        self.last: dict = {}  # the last call: horizon, programs solved (LPs or branch and bounds), reward

    def plan_horizon(self, I: np.ndarray) -> int:
        """The steps to plan for intruders I: (N^2,) float64 (see the class's horizon); 0 with none."""
        return plan_horizon(self.config, I, self.horizon)

    def probabilities(self, D, I):
        """The first step of the best plan found (see the class)."""
        x = D * self.config.n_defenders
        H = self.plan_horizon(I)
        self.last = {"horizon": H, "programs": 0, "reward": None}
        net = self.network(x, I, H) if H > 0 else None
        if net is None:
            return self.place(x, np.zeros(len(self.src)), I, lambda s, d, a: True)
        exact = H == 1
        best = None
        rho, score = np.zeros((H + 1, len(x))), np.zeros((H + 1, len(x)))
        for _ in range(self.iterations if H > 1 else 1):
            M, g = self.nominal(I, H, rho, score)
            choice, flows, _ = self.solve_levels(net, self.values(net, M, g), exact, self.rounds, self.time_limit)
            if choice is None:
                break
            reward, rho, score = self.simulate(net, I, H, choice)
            if best is None or reward > best[0] + 1e-12:
                best = (reward, flows)
        if best is None:
            return self.place(x, np.zeros(len(self.src)), I, lambda s, d, a: True)
        self.last["reward"] = best[0]
        return self.first_step(x, net, best[1], I)

    # ----- the model over the horizon ---------------------------------------------
    def nominal(self, I, H, rho, score):
        """The model around a plan: rho, score: (H+1, N^2) float64 the plan's removed share and
        score per unit of mass at each step's cells (row 0 unused). Returns (M, g): (H+1,
        N^2) float64 each, M[k] the intruders before step k's engagements, g[k] the reward
        per unit of intruder mass left after them, over the rest of the horizon."""
        cfg = self.config
        M = np.zeros((H + 1, len(I)))
        after = I
        for k in range(1, H + 1):
            M[k] = self.A @ after
            after = M[k] * (1 - rho[k])
        g = np.zeros_like(M)
        g[H] = -cfg.c_distribution
        for k in range(H - 1, 0, -1):
            g[k] = (-cfg.c_distribution - cfg.breach_penalty * self.breach
                    + self.A.T @ (cfg.c_capture * score[k + 1] + (1 - rho[k + 1]) * g[k + 1]))
        return M, g

    def values(self, net, M, g) -> np.ndarray:
        """Each target's levels' values around (M, g) (nominal): (T, m + 1) float64, column 0 no game."""
        k, c = net["targets"][:, 0], net["targets"][:, 1]
        mass = M[k, c]
        n_e = team_sizes(self.config, np.zeros(len(k)), mass)[1]
        removed, score = self.rates.grid(self.levels.sizes, n_e)
        V = mass[:, None] * (self.config.c_capture * score - removed * g[k, c][:, None])
        V = np.where(mass[:, None] > self.config.engage_min_mass, V, 0.0)
        return np.hstack([np.zeros((len(k), 1)), V])

    def simulate(self, net, I, H, choice):
        """The env's expected reward over the horizon of a plan, as the env computes it.

        choice: (T,) int64 each target's level. Returns (reward: float, rho, score: (H+1,
        N^2) float64 the plan's removed shares and scores per unit of mass).
        """
        cfg = self.config
        T = net["targets"]
        rho, score = np.zeros((H + 1, len(I))), np.zeros((H + 1, len(I)))
        reward, after = 0.0, I
        for k in range(1, H + 1):
            M = self.A @ after
            breach = float(self.breach @ after)
            at = np.flatnonzero((T[:, 0] == k) & (choice > 0))
            at = at[M[T[at, 1]] > cfg.engage_min_mass]
            if len(at):
                cells = T[at, 1]
                n_e = team_sizes(cfg, np.zeros(len(at)), M[cells])[1]
                rho[k, cells], score[k, cells] = self.rates.get(self.levels.sizes[choice[at] - 1], n_e)
            after = M * (1 - rho[k])
            reward += -cfg.c_distribution * after.sum() + cfg.c_capture * float(M @ score[k]) \
                - cfg.breach_penalty * breach
        return reward, rho, score

    def network(self, x, I, H):
        """The program's network (flow_network) for defender counts x: (N^2,) float64 and
        intruders I: (N^2,) float64 over H steps, the targets the cells the intruders will hold
        under their known advance; None when no defender can reach a target."""
        target = np.zeros((H + 1, len(I)), dtype=bool)
        after = I
        for k in range(1, H + 1):
            after = self.A @ after
            target[k] = after > self.config.engage_min_mass
        return self.flow_network(x, target)
