"""The `minimax` planner (Minimax): a plan over the next H steps against the intruders' worst
replies (scipy.optimize, HiGHS), max over the plans of the min over adversarial courses; the
first step applied."""

from __future__ import annotations

import itertools

import numpy as np
from scipy import sparse

from farm.alloc.allocators.planners.core import MAX_PLANS, _count, _Planner, _positive_number, plan_horizon
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.model import route_intruders_many, team_sizes
from farm.core.errors import ConfigError

__all__ = ["Minimax"]

_OBJECTIVES = ("eliminated", "reward")
REPLIES = ("fewest_ahead", "least_defended", "split_away")  # the heuristic intruders whose replies are courses


class Minimax(_Planner):
    """Plans H steps against the intruders' worst replies: max over plans, min over courses.

    The plan is RecedingHorizon's program (core.flow_network: continuous flows of the
    defenders' mass along each step's feasible moves, one level of levels() chosen at each
    target), its targets every (step, cell) some routing of the intruders can put mass on
    (cone(): a cell's mass reaches its own row and the two beside it, a column left each
    step). A course is a routing of the intruders for each of the H steps, each cell's
    shares sent up-left and down-left (farm.alloc.game.model.route_intruders_many). For a fixed
    course a plan's value (the mass eliminated over the horizon, or the env's reward:
    `objective`) is linear in the level indicators z around a nominal plan, each level
    valued as RecedingHorizon values one (level_values): the mass M the course lands on
    the cell times what the level's game removes or scores there (the capture-time
    statistics at the n_e of that M), net of what the removed mass would have given later
    under that course. The program, solved for the flows, z and t:

        max  r t + (1 - r) V_0(z)   s.t.  t <= V_s(z) for every course s,

    with r the `robustness` and course 0 the config's drift law (the intruders every
    other planner assumes): r = 1 maximises the worst case over the courses, r = 0 is
    RecedingHorizon's plan for the mass eliminated, and the values between trace the
    trade-off between the two.

    Courses, by cutting planes. At first: the drift law; every row straight; every row
    converging on row t, for each t; and, when the defenders can meet the intruders' next
    cells, each pure routing of the intruders now on the grid followed by straight (when
    they number at most `courses`). Then, after each program, the intruders' replies to
    its plan, seen whole (replies()): a beam search over their pure routings (from each
    kept state every pure routing, when it has at most `routings`; the `beam` lowest totals
    kept, a state reached twice kept once) and the intruder policies named by `replies`
    answering the plan's densities step by step; the replies worse than the plan's worst
    course are added, and the program is solved again around the plan just found, at
    most `iterations` times. The plan kept is the one whose simulated worst case (over the
    courses and the replies found) and drift value, mixed by r, are best; its first step
    is applied and the next call plans again from what the intruders actually did.

    Why it is right for one step (H = 1): every level's value is then exact, every pure
    routing is a course and the program is solved by branch and bound: the defenders'
    best move against the follower's worst pure routing (tested against brute force). Pure
    routings are the follower's best responses where a cell's eliminated mass is concave
    in the mass it receives, as when the removed share falls with n_e. With H > 1 the plan
    is open loop, one plan against every course, a conservative model of a game in which
    the defenders see each reply before their next move; a picket holding every row the
    intruders can reach is such a plan, and planning again at each call closes the loop.

    Solving: branch and bound (scipy.optimize.milp) when H = 1 or the program has at most
    `branch_levels` level variables; else the LP relaxation and relax-and-fix (`rounds`),
    as RecedingHorizon (core.solve_levels).

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings(); horizon:
    int >= 1 or None (default: until the intruders now on the grid breach, plan_horizon);
    robustness: r, a number in [0, 1] (default `0.35`); objective: "eliminated" (default)
    or "reward"; iterations: int >= 1 (default 4); courses: int >= 0 (default 256);
    routings: int >= 1 (default 4096); beam: int >= 1 (default 8); replies: intruder
    policy names (default the heuristics fewest_ahead, least_defended and split_away);
    branch_levels: int >= 0 (default 0: branch and bound for H = 1 only); rounds: int >= 1
    (default 2); time_limit: seconds for a branch and bound (default 10); ties:
    Intercept's, for the unused mass; estimates: take the service's interpolation of a pair
    not yet computed (default False). A bad value, a missing client or an unknown option
    is a ConfigError naming it.

    Attribute last: the last call's dict: horizon (int), programs (int, the LPs and branch
    and bounds solved), courses (int, at the end), worst (float: the kept plan's worst
    simulated value over the courses and replies found), drift (float: its value under
    the drift law), bound (float: its program's t) and levels ((H+1, N^2) int64: its level
    at each step's cells); None where no plan was made.
    """

    name = "minimax"

    def __init__(self, config: AllocConfig, client=None, *, horizon: int | None = None, robustness: float = 0.35,
                 objective: str = "eliminated", iterations: int = 4, courses: int = 256, routings: int = 4096,
                 beam: int = 8, replies: tuple | list = REPLIES, branch_levels: int = 0, rounds: int = 2,
                 time_limit: float = 10.0, ties: str = "split", estimates: bool = False, **unknown):
        super().__init__(config, client, unknown, ties)
        self.horizon = None if horizon is None else _count(self.name, "horizon", horizon)
        if isinstance(robustness, bool) or not isinstance(robustness, (int, float, np.integer, np.floating)) \
                or not 0.0 <= robustness <= 1.0:
            raise ConfigError(f"{self.name}: robustness must be a number in [0, 1], got {robustness!r}")
        self.robustness = float(robustness)
        if objective not in _OBJECTIVES:
            raise ConfigError(f"{self.name}: objective must be one of {', '.join(_OBJECTIVES)}, got {objective!r}")
        self.objective = objective
        self.iterations = _count(self.name, "iterations", iterations, maximum=MAX_PLANS)
        self.courses = _count(self.name, "courses", courses, minimum=0)
        self.routings = _count(self.name, "routings", routings)
        self.beam = _count(self.name, "beam", beam)
        self.branch_levels = _count(self.name, "branch_levels", branch_levels, minimum=0)
        self.rounds = _count(self.name, "rounds", rounds, maximum=MAX_PLANS)
        self.time_limit = _positive_number(self.name, "time_limit", time_limit)
        self.plan_on_rates(estimates)
        self.repliers = self._reply_policies(replies)
        n = self.n
        self.rows, self.cols = np.divmod(np.arange(n * n), n)
        self._probe = np.random.default_rng(0).random(n * n)  # a state's fingerprint: its product with this
        self.last: dict = {}

    def _reply_policies(self, names) -> list:
        """The intruder policies (farm.alloc.intruders' registry) named by the option `replies`."""
        from farm.alloc.game.registry import INTRUDERS

        if isinstance(names, str) or not isinstance(names, (list, tuple)):
            raise ConfigError(f"{self.name}: replies must be a list of intruder policies, got {names!r}")
        try:
            return [INTRUDERS.make(name, self.config) for name in names]
        except ConfigError as e:
            raise ConfigError(f"{self.name}: replies: {e}") from None

    # ----- the call ---------------------------------------------------------------
    def probabilities(self, D, I):
        """The first step of the best plan found (see the class)."""
        x = D * self.config.n_defenders
        H = plan_horizon(self.config, I, self.horizon)
        self.last = {"horizon": H, "programs": 0, "courses": 0, "worst": None, "drift": None, "bound": None,
                     "levels": None}
        net = self.flow_network(x, self.cone(I, H)) if H > 0 else None
        if net is None:
            return self.place(x, np.zeros(len(self.src)), I, lambda s, d, a: True)
        best = self.plan(net, x, I, H)
        if best is None:
            return self.place(x, np.zeros(len(self.src)), I, lambda s, d, a: True)
        return self.first_step(x, net, best["flows"], I)

    def plan(self, net, x, I, H):
        """The cutting-plane loop of the class: the kept plan as a dict (flows, levels, worst,
        drift, bound), None when no program found a plan."""
        r = self.robustness
        up, down = self.initial_courses(I, H, first=bool((net["targets"][:, 0] == 1).any()))
        keys = {self._key(u, d) for u, d in zip(up, down, strict=True)}
        nominal = np.zeros((H + 1, self.n * self.n), dtype=np.int64)
        T, m = net["T"], net["m"]
        exact = H == 1 or T * (m + 1) <= self.branch_levels
        best = None
        for _ in range(self.iterations):
            W, const = self.level_values(net, nominal, up, down, I)
            extra = {"c": np.array([r]), "lower": np.array([-np.inf]), "upper": np.array([np.inf]),
                     "rows": self._course_rows(net, W), "lb": np.full(len(W), -np.inf), "ub": const}
            choice, flows, y = self.solve_levels(net, (1.0 - r) * W[0], exact, self.rounds, self.time_limit, extra)
            if choice is None:
                break
            levels = np.zeros_like(nominal)
            levels[net["targets"][:, 0], net["targets"][:, 1]] = choice
            values = self.simulate(levels, up, down, I)[0]
            r_up, r_down, r_values = self.replies(levels, self.plan_densities(net, x, flows, H), I, H)
            worst = min(float(values.min()), float(r_values.min()) if len(r_values) else np.inf)
            score = r * worst + (1.0 - r) * float(values[0])
            if best is None or score > best["score"] + 1e-12:
                best = {"score": score, "flows": flows, "levels": levels, "worst": worst, "drift": float(values[0]),
                        "bound": float(y[0])}
            new = [k for k in np.argsort(r_values, kind="stable") if r_values[k] < values.min() - 1e-9]
            added = 0
            for k in new:
                key = self._key(r_up[k], r_down[k])
                if key not in keys:
                    keys.add(key)
                    up, down = np.concatenate([up, r_up[k][None]]), np.concatenate([down, r_down[k][None]])
                    added += 1
            if not added and (H == 1 or np.array_equal(levels, nominal)):  # with H = 1 the values are exact
                break
            nominal = levels
        self.last["courses"] = len(up)
        if best is not None:
            self.last.update(worst=best["worst"], drift=best["drift"], bound=best["bound"], levels=best["levels"])
        return best

    # ----- the intruders' routings ---------------------------------------------------
    def cone(self, I: np.ndarray, H: int) -> np.ndarray:
        """(H+1, N^2) bool: the cells some routing can put the intruders I: (N^2,) float64 on after
        each of the next H steps (row 0: where they are)."""
        n = self.n
        cone = np.zeros((H + 1, n * n), dtype=bool)
        cone[0] = I > self.config.engage_min_mass
        for k in range(1, H + 1):
            held = cone[k - 1].reshape(n, n)[:, 1:]  # the cells that land one column left
            nxt = np.zeros((n, n), dtype=bool)
            nxt[:, :-1] = held
            nxt[1:, :-1] |= held[:-1]
            nxt[:-1, :-1] |= held[1:]
            cone[k] = nxt.reshape(-1)
        return cone

    def pure_routings(self, I: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Every pure routing of the intruders I: (N^2,) float64: (up, down): (K, N^2) float64 of
        0s and 1s, each cell holding mass (outside column 0, whose mass breaches whatever its
        route) sending it all up-left, left or down-left; None when K would exceed budget."""
        n2 = self.n * self.n
        cells = np.flatnonzero((I > self.config.engage_min_mass) & (self.cols > 0))
        options = [[d for d in (-1, 0, 1) if 0 <= self.rows[c] + d < self.n] for c in cells]
        if np.prod([len(o) for o in options], dtype=np.float64) > budget:
            return None
        if len(cells) == 0:
            return np.zeros((1, n2)), np.zeros((1, n2))
        choice = np.array(list(itertools.product(*options)), dtype=np.int64)
        up, down = np.zeros((len(choice), n2)), np.zeros((len(choice), n2))
        up[:, cells], down[:, cells] = choice == -1, choice == 1
        return up, down

    def structured_routings(self) -> tuple[np.ndarray, np.ndarray]:
        """(up, down): (N + 1, N^2) float64: every cell straight, then every cell moving one row
        towards row t (straight once on it), for t = 0..N-1."""
        step = np.sign(np.arange(self.n)[:, None] - self.rows[None, :])  # (N, N^2) towards row t
        up = np.vstack([np.zeros(self.n * self.n), (step == -1).astype(float)])
        down = np.vstack([np.zeros(self.n * self.n), (step == 1).astype(float)])
        return up, down

    def initial_courses(self, I, H, first: bool) -> tuple[np.ndarray, np.ndarray]:
        """The first courses, (up, down): (S, H, N^2) float64 each: course 0 the drift law at
        every step, then the structured routings held over the horizon, then, when `first` (the
        defenders can meet the intruders' next cells), each pure routing of I followed by
        straight (when there are at most `routings`)."""
        from farm.alloc.game.model import drift_routing

        n2 = self.n * self.n
        d_up, d_down = drift_routing(self.n, self.config.vertical_drift)
        s_up, s_down = self.structured_routings()
        up = [np.repeat(d_up[:, None], H, axis=1), np.repeat(s_up[:, None], H, axis=1)]
        down = [np.repeat(d_down[:, None], H, axis=1), np.repeat(s_down[:, None], H, axis=1)]
        first = self.pure_routings(I, self.courses) if first else None
        if first is not None:
            k = len(first[0])
            for part, lst in zip(first, (up, down), strict=True):
                rest = np.zeros((k, H, n2))
                rest[:, 0] = part
                lst.append(rest)
        return np.concatenate(up), np.concatenate(down)

    def _key(self, up, down) -> bytes:
        return np.concatenate([up.reshape(-1), down.reshape(-1)]).round(12).tobytes()

    # ----- the model of a plan against courses ------------------------------------
    def engage(self, levels_k: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The removed share and score per unit of mass of the plan's games at one step.

        levels_k: (N^2,) int64 each cell's level (0: no game); M: (B, N^2) float64 the intruders
        after their move in B courses -> (rho, score): (B, N^2) float64 each."""
        rho, score = np.zeros(M.shape), np.zeros(M.shape)
        on = (levels_k[None, :] > 0) & (M > self.config.engage_min_mass)
        if on.any():
            b, c = np.nonzero(on)
            n_e = team_sizes(self.config, np.zeros(len(b)), M[b, c])[1]
            removed, scored = self.rates.table(self.levels.sizes, n_e)
            pick = levels_k[c] - 1
            rho[b, c] = removed[np.arange(len(b)), pick]
            score[b, c] = scored[np.arange(len(b)), pick]
        return rho, score

    def step_value(self, M, rho, score, breach) -> np.ndarray:
        """One step's value in each of B courses: M, rho, score: (B, N^2) float64, breach: (B,)
        float64 -> (B,) float64: the mass eliminated, or the env's reward (`objective`)."""
        cfg = self.config
        if self.objective == "eliminated":
            return (M * rho).sum(axis=1)
        return (-cfg.c_distribution * (M * (1 - rho)).sum(axis=1) + cfg.c_capture * (M * score).sum(axis=1)
                - cfg.breach_penalty * breach)

    def simulate(self, levels, up, down, I):
        """A plan against courses, as the env computes them.

        levels: (H+1, N^2) int64 the plan's level at each step's cells (row 0 unused); up,
        down: (S, H, N^2) float64 the courses; I: (N^2,) float64 the intruders now. Returns
        (values: (S,) float64, M, rho, score: (S, H+1, N^2) float64 the intruders before each
        step's engagements and the removed shares and scores there; row 0 unused)."""
        S, H = up.shape[0], up.shape[1]
        M, rho, score = (np.zeros((S, H + 1, len(I))) for _ in range(3))
        values = np.zeros(S)
        after = np.tile(I, (S, 1))
        for k in range(1, H + 1):
            M[:, k], breach = route_intruders_many(after, self.n, up[:, k - 1], down[:, k - 1])
            rho[:, k], score[:, k] = self.engage(levels[k], M[:, k])
            values += self.step_value(M[:, k], rho[:, k], score[:, k], breach)
            after = M[:, k] * (1 - rho[:, k])
        return values, M, rho, score

    def pull(self, G: np.ndarray, up: np.ndarray, down: np.ndarray) -> np.ndarray:
        """The transpose of a routing's advance: G: (S, N^2) float64 a value per unit of mass
        landing on each cell -> (S, N^2) float64 per unit of mass routed from each cell by (up,
        down): (S, N^2) float64 (0 from column 0, whose mass breaches)."""
        n, S = self.n, len(G)
        g, u, d = G.reshape(S, n, n), up.reshape(S, n, n), down.reshape(S, n, n)
        out = np.zeros((S, n, n))
        out[:, :, 1:] = (1 - u[:, :, 1:] - d[:, :, 1:]) * g[:, :, :-1]
        out[:, 1:, 1:] += u[:, 1:, 1:] * g[:, :-1, :-1]
        out[:, :-1, 1:] += d[:, :-1, 1:] * g[:, 1:, :-1]
        return out.reshape(S, n * n)

    def level_values(self, net, nominal, up, down, I):
        """Each course's value linear in the levels around the nominal plan.

        nominal: (H+1, N^2) int64 the nominal plan's levels. Returns (W: (S, T, m + 1) float64
        each target's levels' values per course, const: (S,) float64) such that a plan
        choosing level l_i at target i is worth about const + sum_i W[s, i, l_i] in course s:
        exactly the nominal plan's value, and exactly the value of the nominal plan with one
        target's level changed when that changes no later game (RecedingHorizon.nominal).
        W is M (removed (1 - g)) for the eliminated mass, M (c_capture score - removed g) for
        the reward, g the value per unit of mass left after the engagement over the rest of
        the horizon under the course's routing and the nominal plan's later games."""
        cfg = self.config
        values, M, rho, score = self.simulate(nominal, up, down, I)
        S, H = up.shape[0], up.shape[1]
        g = np.zeros((S, H + 1, len(I)))
        reward = self.objective == "reward"
        breaches = (self.cols == 0).astype(float)[None, :]
        g[:, H] = -cfg.c_distribution if reward else 0.0
        for k in range(H - 1, 0, -1):
            if reward:
                gain = cfg.c_capture * score[:, k + 1] + (1 - rho[:, k + 1]) * g[:, k + 1]
                g[:, k] = -cfg.c_distribution - cfg.breach_penalty * breaches + self.pull(gain, up[:, k], down[:, k])
            else:
                g[:, k] = self.pull(rho[:, k + 1] + (1 - rho[:, k + 1]) * g[:, k + 1], up[:, k], down[:, k])
        tk, tc = net["targets"][:, 0], net["targets"][:, 1]
        mass, gt = M[:, tk, tc], g[:, tk, tc]  # (S, T)
        n_e = team_sizes(cfg, np.zeros(mass.size), mass.reshape(-1))[1].reshape(mass.shape)
        removed, scored = self.rates.table(self.levels.sizes, n_e)  # (S, T, m)
        if reward:
            W = mass[..., None] * (cfg.c_capture * scored - removed * gt[..., None])
        else:
            W = mass[..., None] * removed * (1 - gt[..., None])
        W = np.where(mass[..., None] > cfg.engage_min_mass, W, 0.0)
        W = np.concatenate([np.zeros((S, len(tk), 1)), W], axis=2)
        const = values - W[:, np.arange(len(tk)), nominal[tk, tc]].sum(axis=1)
        return W, const

    def _course_rows(self, net, W) -> sparse.csr_array:
        """The rows t - sum_i W[s, i, l] z_il <= const[s] over the program's variables (edges, levels, t)."""
        S = len(W)
        return sparse.hstack([sparse.csr_array((S, net["E"])), sparse.csr_array(-W.reshape(S, -1)),
                              sparse.csr_array(np.ones((S, 1)))], format="csr")

    # ----- the intruders' replies to a plan ------------------------------------------
    def plan_densities(self, net, x, flows, H) -> np.ndarray:
        """(H+1, N^2) float64: the plan's defender densities after each step (row 0: now) of H."""
        D = np.zeros((H + 1, len(x)))
        D[0] = x
        np.add.at(D, (net["edges"][:, 0], net["edges"][:, 2]), flows)
        return D / self.config.n_defenders

    def replies(self, levels, D_plan, I, H):
        """The intruders' worst replies found to a plan seen whole: the beam search's final states
        and each heuristic's reply (see the class). levels: (H+1, N^2) int64; D_plan: (H+1, N^2)
        float64 the plan's densities. Returns (up, down: (R, H, N^2) float64, values: (R,) float64)."""
        n2 = self.n * self.n
        after, acc = I[None].copy(), np.zeros(1)
        seq_up, seq_down = np.zeros((1, H, n2)), np.zeros((1, H, n2))
        s_up, s_down = self.structured_routings()
        for k in range(1, H + 1):
            parents, ups, downs = [], [], []
            for b in range(len(after)):
                routes = self.pure_routings(after[b], self.routings)
                if routes is None:
                    h_up, h_down = zip(*(h.routing(D_plan[k][None], after[b][None]) for h in self.repliers),
                                       strict=True)
                    routes = (np.vstack([s_up, *h_up]), np.vstack([s_down, *h_down]))
                parents.append(np.full(len(routes[0]), b))
                ups.append(routes[0])
                downs.append(routes[1])
            parent, u, d = np.concatenate(parents), np.vstack(ups), np.vstack(downs)
            M, breach = route_intruders_many(after[parent], self.n, u, d)
            rho, score = self.engage(levels[k], M)
            total = acc[parent] + self.step_value(M, rho, score, breach)
            state = M * (1 - rho)
            order = np.argsort(total, kind="stable")
            _, first = np.unique(state[order].round(12) @ self._probe, return_index=True)  # states reached twice
            keep = order[np.sort(first)][: self.beam]
            after, acc = state[keep], total[keep]
            seq_up, seq_down = seq_up[parent[keep]], seq_down[parent[keep]]
            seq_up[:, k - 1], seq_down[:, k - 1] = u[keep], d[keep]
        h_up, h_down = self.heuristic_replies(levels, D_plan, I, H)
        up, down = np.concatenate([seq_up, h_up]), np.concatenate([seq_down, h_down])
        return up, down, self.simulate(levels, up, down, I)[0]

    def heuristic_replies(self, levels, D_plan, I, H):
        """Each registered heuristic intruder policy replying step by step to the plan's densities
        D_plan: (H+1, N^2) float64 (it sees the defenders after their move, as a follower):
        (up, down): (h, H, N^2) float64."""
        h = len(self.repliers)
        up, down = np.zeros((h, H, len(I))), np.zeros((h, H, len(I)))
        after = np.tile(I, (h, 1))
        for k in range(1, H + 1):
            for j, policy in enumerate(self.repliers):
                u, d = policy.routing(D_plan[k][None], after[j][None])
                up[j, k - 1], down[j, k - 1] = u[0], d[0]
            M, _ = route_intruders_many(after, self.n, up[:, k - 1], down[:, k - 1])
            rho, _ = self.engage(levels[k], M)
            after = M * (1 - rho)
        return up, down
