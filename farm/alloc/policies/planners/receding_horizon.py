"""The `receding_horizon` planner (RecedingHorizon): a program over the next H steps
(scipy.optimize, HiGHS) maximising the env's own expected reward; the first step applied."""

from __future__ import annotations

import numpy as np

from farm.alloc.config import AllocConfig
from farm.alloc.model import team_sizes
from farm.alloc.policies.planners.core import _TINY, _Planner, _count, _positive_number

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
        self.iterations = _count("receding_horizon", "iterations", iterations)
        self.rounds = _count("receding_horizon", "rounds", rounds)
        self.time_limit = _positive_number("receding_horizon", "time_limit", time_limit)
        self.plan_on_rates(estimates)
        self.last: dict = {}  # the last call: horizon, programs solved (LPs or branch and bounds), reward

    def plan_horizon(self, I: np.ndarray) -> int:
        """The steps to plan for intruders I: (N^2,) float64 (see the class's horizon); 0 with none."""
        n = self.n
        cols = np.flatnonzero(I.reshape(n, n).max(axis=0) > self.config.engage_min_mass)
        if len(cols) == 0:
            return 0
        c_max = int(cols[-1])
        left = self.config.max_steps - (n - 1 - c_max)
        return max(1, min(self.horizon or c_max + 1, c_max + 1, left))

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
            choice, flows = self.solve(net, self.values(net, M, g), exact)
            if choice is None:
                break
            reward, rho, score = self.simulate(net, I, H, choice)
            if best is None or reward > best[0] + 1e-12:
                best = (reward, flows)
        if best is None:
            return self.place(x, np.zeros(len(self.src)), I, lambda s, d, a: True)
        self.last["reward"] = best[0]
        first = np.zeros(len(self.src))
        np.add.at(first, net["first_moves"], best[1][net["first"]])
        count = np.bincount(self.dst, weights=first, minlength=len(x))
        on_target = set(net["targets"][net["targets"][:, 0] == 1, 1].tolist())

        def keep(s, d, amount):  # on a first-step target only when its game stays the planned one
            if d in on_target and self.levels.of([count[d] + amount])[0] != self.levels.of([count[d]])[0]:
                return False
            count[d] += amount
            return True

        return self.place(x, first, I, keep)

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

    # ----- the program --------------------------------------------------------------
    def network(self, x, I, H):
        """The program's network for defender counts x: (N^2,) float64 and intruders I over H steps.

        None when no defender can reach a target. Else a dict: targets (T, 2) int64
        (step, cell); T; m (the levels); edges (E, 3) int64 (step, from, to); E; matrix,
        lb, ub (the constraints: conservation, then per target the one-hot row and the
        inflow's range); upper (E + T (m + 1),) float64 the variables' upper bounds;
        inflow (T, E) sparse; first (E,) bool the first step's edges and first_moves their
        action indices.
        """
        from scipy import sparse

        cfg, n2, L = self.config, self.n * self.n, self.levels
        target = np.zeros((H + 1, n2), dtype=bool)
        after = I
        for k in range(1, H + 1):
            after = self.A @ after
            target[k] = after > cfg.engage_min_mass

        def dilate(mask):
            return np.bincount(self.src, weights=mask[self.dst].astype(float), minlength=n2) > 0

        reach = np.zeros((H + 1, n2), dtype=bool)
        reach[0] = x > _TINY
        for k in range(1, H + 1):
            reach[k] = dilate(reach[k - 1])
        useful = np.zeros_like(reach)
        useful[H] = target[H]
        for k in range(H - 1, -1, -1):
            useful[k] = target[k] | dilate(useful[k + 1])
        node = reach & useful
        tk, tc = np.nonzero(node & target)
        if len(tk) == 0:
            return None
        T, m = len(tk), len(L.sizes)
        edges = np.concatenate([np.stack([np.full(int(sel.sum()), k), self.src[sel], self.dst[sel]], axis=1)
                                for k in range(1, H + 1)
                                for sel in [node[k - 1][self.src] & node[k][self.dst]]]).astype(np.int64)
        E = len(edges)
        node_id = np.full((H + 1, n2), -1)
        node_id[node] = np.arange(int(node.sum()))
        out_node = node_id[edges[:, 0] - 1, edges[:, 1]]
        in_node = node_id[edges[:, 0], edges[:, 2]]
        n_nodes = int(node.sum())
        # conservation, one row per node with outgoing edges: out - in <= 0 (x at step 0); = when closed
        outs = np.bincount(out_node, minlength=n_nodes)
        rows_of = np.full(n_nodes, -1)
        has_out = np.flatnonzero(outs > 0)
        rows_of[has_out] = np.arange(len(has_out))
        e_idx = np.arange(E)
        in_row = rows_of[in_node]
        rows = [rows_of[out_node], in_row[in_row >= 0]]
        cols = [e_idx, e_idx[in_row >= 0]]
        vals = [np.ones(E), -np.ones(int((in_row >= 0).sum()))]
        node_k, node_c = np.nonzero(node)
        n_moves = self.ends - self.start
        closed = outs[has_out] == n_moves[node_c[has_out]]
        rhs = np.where(node_k[has_out] == 0, x[node_c[has_out]], 0.0)
        lb = [np.where(closed, rhs, -np.inf)]
        ub = [rhs]
        r0 = len(has_out)
        # targets: one-hot; inflow - sum lo z >= 0; inflow - sum hi z <= 0
        cap = np.array([x[self.cheb[c] <= k].sum() for k, c in zip(tk, tc)])  # the most a target can get
        lo = np.concatenate([[0.0], L.lo])
        t_of = np.full((H + 1, n2), -1)
        t_of[tk, tc] = np.arange(T)
        e_t = t_of[edges[:, 0], edges[:, 2]]
        into = np.flatnonzero(e_t >= 0)
        z = E + np.arange(T * (m + 1)).reshape(T, m + 1)
        hi = np.concatenate([np.full((T, 1), L.zero_hi), np.minimum(L.hi[None, :], cap[:, None] + 1.0)], axis=1)
        t_rows = np.repeat(np.arange(T), m + 1)
        rows += [r0 + t_rows, r0 + T + e_t[into], r0 + T + t_rows, r0 + 2 * T + e_t[into], r0 + 2 * T + t_rows]
        cols += [z.reshape(-1), into, z.reshape(-1), into, z.reshape(-1)]
        vals += [np.ones(T * (m + 1)), np.ones(len(into)), -np.tile(lo, T), np.ones(len(into)), -hi.reshape(-1)]
        lb += [np.ones(T), np.zeros(T), np.full(T, -np.inf)]
        ub += [np.ones(T), np.full(T, np.inf), np.zeros(T)]
        matrix = sparse.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                  shape=(r0 + 3 * T, E + T * (m + 1)))
        upper = np.full(E + T * (m + 1), np.inf)
        fillable = np.concatenate([np.ones((T, 1)), lo[None, 1:] <= cap[:, None] + 1e-9], axis=1)
        upper[E:] = fillable.reshape(-1)
        first = edges[:, 0] == 1
        inflow = sparse.csr_array((np.ones(len(into)), (e_t[into], into)), shape=(T, E))
        return {"targets": np.stack([tk, tc], axis=1), "T": T, "m": m, "edges": edges, "E": E, "matrix": matrix,
                "lb": np.concatenate(lb), "ub": np.concatenate(ub), "upper": upper, "inflow": inflow,
                "first": first, "first_moves": self.move_index(edges[first, 1], edges[first, 2])}

    def solve(self, net, V: np.ndarray, exact: bool):
        """Solve the program for level values V: (T, m + 1) float64 (see the class: exact is
        branch and bound, else relax-and-fix). Returns (choice: (T,) int64 the chosen
        levels, flows: (E,) float64) or (None, None) when no plan was found."""
        from scipy.optimize import Bounds, LinearConstraint, milp

        E, m, T = net["E"], net["m"], net["T"]
        c = np.concatenate([np.zeros(E), -(V / max(float(np.abs(V).max()), 1e-300)).reshape(-1)])
        constraints = LinearConstraint(net["matrix"], net["lb"], net["ub"])
        integrality = np.concatenate([np.zeros(E), np.full(T * (m + 1), 1 if exact else 0)])
        lower, upper = np.zeros(len(c)), net["upper"].copy()
        lo = np.concatenate([[0.0], self.levels.lo])
        fixed = np.zeros(T, dtype=bool)
        undo, rounds = None, 0
        options = {"time_limit": self.time_limit, "mip_rel_gap": 0.0} if exact else {"presolve": False}
        while True:
            res = milp(c, constraints=constraints, integrality=integrality, bounds=Bounds(lower, upper),
                       options=options)
            self.last["programs"] += 1
            if res.x is None:
                if undo is None:
                    return None, None
                lower, upper, fixed, just_fixed = undo  # cap the targets just fixed instead
                for i, a in just_fixed:
                    upper[E + i * (m + 1) + a + 1: E + (i + 1) * (m + 1)] = 0.0
                undo = None
                continue
            zs = res.x[E:].reshape(T, m + 1)
            mixed = (zs.max(axis=1) < 1 - 1e-6) & ~fixed
            if exact or not mixed.any():
                return np.argmax(zs, axis=1), res.x[:E]
            rounds += 1
            inflow = net["inflow"] @ res.x[:E]
            undo = (lower.copy(), upper.copy(), fixed.copy(), [])
            if rounds >= self.rounds:
                mixed = ~fixed  # the last round fixes every target
            else:
                for i in np.flatnonzero(~mixed & ~fixed):  # whole levels may only go up
                    upper[E + i * (m + 1): E + i * (m + 1) + int(np.argmax(zs[i]))] = 0.0
            for i in np.flatnonzero(mixed):
                allowed = np.flatnonzero(upper[E + i * (m + 1): E + (i + 1) * (m + 1)] > 0)
                filled = allowed[lo[allowed] <= inflow[i] + 1e-9]
                a = int(filled.max()) if len(filled) else int(allowed.min())
                upper[E + i * (m + 1): E + (i + 1) * (m + 1)] = 0.0
                upper[E + i * (m + 1) + a] = lower[E + i * (m + 1) + a] = 1.0
                fixed[i] = True
                undo[3].append((i, a))
