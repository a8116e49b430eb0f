"""The planners (farm.alloc.allocators.planners, docs/model.md section 7) on hand-made states whose best move is known.

Most cases use a client over a hand-made capture curve (Curve: every game's statistics
chosen by a function of its team sizes), so that the expected moves can be worked out by
hand; one fixture uses small real games (3 per case) in a store under tmp_path.
"""

import inspect
import itertools
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.allocators import allocator_entry, allocator_names, make_allocator
from farm.alloc.allocators.baselines import GreedyNearestIntruder
from farm.alloc.allocators.planners import (
    Intercept,
    MaxMarginalReturn,
    RecedingHorizon,
    Transport,
    action_from_probabilities,
    levels,
)
from farm.alloc.allocators.planners.transport import apportion
from farm.alloc.game.model import advance_intruders, team_sizes
from farm.core.errors import ConfigError, InputError
from farm.service import CaptureTimeClient
from farm.service.lookup import Lookup
from workers import CaptureStats, game_statistics

GAMES = 64  # the curve's games per case: shares are multiples of 1 / (64 n_e)


class Curve(Lookup):
    """A lookup without a store whose games catch the share f(n_p, n_e) of the intruders at tau/2."""

    repeatable = True

    def __init__(self, f):
        def compute(keys):
            for k, key in enumerate(keys):
                n_p, n_e, tau = key.case.n_pursuers, key.case.n_evaders, key.case.tau
                t = np.full(GAMES * n_e, np.nan)
                t[: int(round(f(n_p, n_e) * GAMES * n_e))] = tau / 2
                yield k, CaptureStats.from_games(game_statistics(t.reshape(GAMES, n_e), tau))
        super().__init__(None, compute)


def concave(n_p, n_e):
    """The default curve: 0.9 n_p / (n_p + n_e), concave in n_p."""
    return min(1.0, 0.9 * n_p / (n_p + n_e))


_CLIENTS: dict = {}


def curve_client(config, f=concave):
    """A client of config whose games catch f(n_p, n_e) of the intruders, one per (settings, f)."""
    key = (config.game_settings(), f)
    if key not in _CLIENTS:
        _CLIENTS[key] = CaptureTimeClient(config.game_settings(), backend=Curve(f))
    return _CLIENTS[key]


def cfg_of(**kw):
    """A 3x3 config of 10 defenders v 5 intruders on the lattice, kw replacing settings."""
    return AllocConfig(**{"grid_size": 3, "n_defenders": 10, "n_intruders": 5, "games": 3, "team_sizes": "lattice",
                          **kw})


def env_at(config, client, D, I):
    """An env set to the densities D, I: (N^2,) float64."""
    env = SwarmAllocationEnv(config, client=client)
    env.reset(seed=0)
    env.D, env.I = np.asarray(D, dtype=float).copy(), np.asarray(I, dtype=float).copy()
    return env


def realised(env, action) -> np.ndarray:
    """D' = T D of an action in env (the env's own map): (N^2,) float64."""
    p = env.move_probabilities(action)
    return np.bincount(env.dst, weights=p * env.D[env.src], minlength=len(env.D))


def cells(n, *rc):
    """Cell indices of (row, col) pairs on an n x n grid."""
    return [r * n + c for r, c in rc]


def density(n, **at):
    """(n^2,) float64 with at[cell] = mass (keys like c4 for cell 4)."""
    d = np.zeros(n * n)
    for k, v in at.items():
        d[int(k[1:])] = v
    return d


def obs_of(D, I):
    """The observation of densities D, I: (2 N^2,) float32."""
    return np.concatenate([D, I]).astype(np.float32)


def as_observed(D, I):
    """D, I as the planners see them (float32), back in float64: the brute forces' inputs."""
    return D.astype(np.float32).astype(np.float64), I.astype(np.float32).astype(np.float64)


ALL = allocator_names("planner", references=True)  # subregions on a small map is receding_horizon: its own tests below


@pytest.fixture(scope="module")
def real_client(tmp_path_factory):
    """A client of cfg_of() over a small real store (3 games per case)."""
    client = CaptureTimeClient(cfg_of().game_settings(), local_store=tmp_path_factory.mktemp("s") / "s.sqlite")
    yield client
    client.close()


# ----------------------------------------------------------------------------- the action helper
@pytest.mark.parametrize("action_map", ["softmax", "shifted"])
@pytest.mark.parametrize("n", [3, 5])
def test_action_realises_the_wanted_moves(action_map, n, rng):
    """The env's action_map gives back the wanted probabilities: exactly under shifted; under
    softmax up to the floor exp(-2 beta) p_max that clipping at -1 leaves on unwanted moves."""
    cfg = AllocConfig(grid_size=n, action_map=action_map)
    env = SwarmAllocationEnv(cfg, client=curve_client(cfg))
    for _ in range(20):
        w = rng.random(len(env.src)) * (rng.random(len(env.src)) < 0.5)  # half the moves unwanted
        w[env.start] += 1e-3 * (w[env.start] == 0)  # no cell without a wanted move
        p = w / np.add.reduceat(w, env.start)[env.src]
        env.D = rng.dirichlet(np.ones(n * n))
        action = action_from_probabilities(cfg, p, env.start, env.src)
        assert action.dtype == np.float32 and action.shape == env.action_space.shape
        assert np.all(np.abs(action) <= 1)
        got = env.move_probabilities(action)
        want_D = np.bincount(env.dst, weights=p * env.D[env.src], minlength=n * n)
        if action_map == "shifted":
            np.testing.assert_allclose(got, p, atol=1e-6)
            np.testing.assert_allclose(realised(env, action), want_D, atol=1e-6)
        else:
            p_max = np.maximum.reduceat(p, env.start)[env.src]
            floor = np.maximum(p, p_max * math.exp(-2 * cfg.softmax_beta))
            np.testing.assert_allclose(got, floor / np.add.reduceat(floor, env.start)[env.src], rtol=1e-5, atol=1e-9)
            leak = (env.n_moves - 1) * math.exp(-2 * cfg.softmax_beta)  # the most a cell can lose
            assert np.abs(realised(env, action) - want_D).max() <= (leak * env.D).sum() + 1e-6
            assert np.abs(realised(env, action) - want_D).max() <= 4e-4


def test_levels_are_the_games_team_sizes_plays():
    """Every count in a level's range plays that level's game (team_sizes), margins included."""
    for cfg in (AllocConfig(n_defenders=800, team_sizes="lattice"), AllocConfig(n_defenders=100, team_sizes="lattice"),
                AllocConfig(n_defenders=30, action_map="shifted", team_sizes="lattice")):
        L = levels(cfg)
        for i, size in enumerate(L.sizes):
            top = min(L.hi[i], cfg.n_defenders + 0.4)
            counts = np.linspace(L.lo[i], top, 50)
            n_p = team_sizes(cfg, counts / cfg.n_defenders, np.ones(50))[0]
            assert set(n_p.tolist()) == {size}, (i, size)
        assert team_sizes(cfg, np.array([L.zero_hi / cfg.n_defenders]), np.ones(1))[0][0] == 0


# ----------------------------------------------------------------------------- known best moves
@pytest.mark.parametrize("name", ALL)
def test_a_single_reachable_intruder_cell_gets_the_mass(name):
    """Defenders in the centre; the only intruders (row 0, col 2) advance to (0, 1), next to them:
    all the defenders go there (with more defenders always catching more, the biggest game)."""
    cfg = cfg_of()
    client = curve_client(cfg)
    D, I = density(3, c4=1.0), density(3, c2=0.4)
    planner = make_allocator(name, cfg, client)
    env = env_at(cfg, client, D, I)
    action, _ = planner.predict(obs_of(D, I))
    D1 = realised(env, action)
    target = cells(3, (0, 1))[0]
    assert team_sizes(cfg, D1[[target]], np.ones(1))[0][0] == 12  # 10 defenders round and snap to 12
    assert D1[target] > 0.95
    _, _, _, _, info = env.step(action)
    assert info["engaged_cells"] == 1 and info["defenders_per_engaged"] == 12


@pytest.mark.parametrize("name", ALL)
@pytest.mark.parametrize("where", [(1, 0), (1, 1)])
def test_no_swap(name, where):
    """Defenders in column c, intruders in column c + 1 of the same row: the defenders wait to be
    met (stay) rather than cross them, and the engagement happens; greedy_nearest crosses them."""
    cfg = cfg_of()
    client = curve_client(cfg)
    d = cells(3, where)[0]
    D, I = density(3), density(3)
    D[d], I[d + 1] = 1.0, 0.5
    action, _ = make_allocator(name, cfg, client).predict(obs_of(D, I))
    env = env_at(cfg, client, D, I)
    assert realised(env, action)[d] > 0.95
    _, _, _, _, info = env.step(action)
    assert info["engaged_cells"] == 1 and info["eliminated_step"] > 0
    greedy, _ = GreedyNearestIntruder(3).predict(obs_of(D, I))
    env = env_at(cfg, client, D, I)
    assert realised(env, greedy)[d + 1] > 0.95
    assert env.step(greedy)[4]["engaged_cells"] == 0


def test_intercept_anticipates_the_advance():
    """8x8, defenders at the base (4, 0), one intruder cell at (0, 7): the earliest meeting is 4 steps
    on at (0, 3) (4 king moves away), so the first move is up-right to (3, 1); greedy_nearest heads
    for (0, 7) itself. With two intruder cells met equally early, ties split the mass by their
    intruder mass (or all to the largest)."""
    cfg = AllocConfig(grid_size=8, n_defenders=800, n_intruders=400)
    D, I = density(8), density(8)
    D[32], I[7] = 1.0, 0.3
    p = Intercept(cfg).probabilities(D, I)
    env = env_at(cfg, curve_client(cfg), D, I)
    env_p = realised(env, action_from_probabilities(cfg, p, env.start, env.src))
    assert env_p[cells(8, (3, 1))[0]] > 0.99
    I[cells(8, (7, 7))[0]] = 0.1
    share = Intercept(cfg).meetings(I)[32]
    assert share[cells(8, (0, 3))[0]] == pytest.approx(0.75) and share[cells(8, (7, 3))[0]] == pytest.approx(0.25)
    assert Intercept(cfg, ties="largest").meetings(I)[32][cells(8, (0, 3))[0]] == 1.0


def _apportion_slowly(units, weights):
    """Hamilton's method the obvious way: each whole quota, then one unit at a time to the largest
    remainder left (the lowest index on ties: remainders equal to 9 decimals)."""
    quota = [units * w / sum(weights) for w in weights]
    whole = [math.floor(q) for q in quota]
    rest = [round(q - f, 9) for q, f in zip(quota, whole)]
    for _ in range(units - sum(whole)):
        k = max(range(len(rest)), key=lambda i: (rest[i], -i))
        whole[k], rest[k] = whole[k] + 1, -1.0
    return whole


@settings(max_examples=50, deadline=None)
@given(units=st.integers(0, 40), weights=st.lists(st.sampled_from([0.0, 0.1, 0.25, 1.0, 3.0, 7.5]), min_size=1,
                                                   max_size=12).filter(lambda w: sum(w) > 0))
@example(units=24, weights=[0.1, 0.25, 1.0, 3.0, 0.1, 0.1, 0.25, 1.0])  # remainders tied but for rounding
def test_transport_apportions_whole_units_by_largest_remainders(units, weights):
    whole = apportion(units, np.array(weights))
    assert whole.tolist() == _apportion_slowly(units, weights)
    assert whole.sum() == units and np.all(np.abs(whole - units * np.array(weights) / sum(weights)) < 1)


def _run_moves(planner, cfg, D, I, steps):
    """D after `steps` steps of the planner's move probabilities, the intruders advancing (drift
    included) and never engaged: (N^2,) float64 each step, the probabilities applied exactly."""
    src, dst = planner.src, planner.dst
    out = []
    for _ in range(steps):
        D = np.bincount(dst, weights=planner.probabilities(D, I) * D[src], minlength=len(D))
        I = advance_intruders(I, cfg.grid_size, cfg.vertical_drift)[0]
        out.append(D)
    return out


def test_transport_sends_one_defender_to_each_row_of_a_front_where_intercept_diffuses():
    """16 x 16, 16 defenders at the base (8, 0), the same intruder mass on every row of the right-most
    column, no drift: every row's intruders can be met 8 steps on, in column 7. Transport matches the
    defenders to the rows once (one unit a row) and each unit travels straight: after 8 steps every
    cell of column 7 holds exactly one defender. Intercept re-splits its mass each step among the
    rows it can still meet as early, so the outer rows get a fraction of a defender (no game)."""
    n = 16
    cfg = AllocConfig(grid_size=n, n_defenders=16, n_intruders=1600, max_steps=n, team_sizes="lattice")
    D, I = np.zeros(n * n), np.zeros(n * n)
    D[8 * n] = 1.0
    I[np.arange(n) * n + n - 1] = 0.5 / n
    column_7 = np.arange(n) * n + 7
    D8 = _run_moves(Transport(cfg), cfg, D, I, 8)[-1]
    np.testing.assert_allclose(D8[column_7] * cfg.n_defenders, 1.0, rtol=0, atol=1e-12)
    intercept_8 = _run_moves(Intercept(cfg), cfg, D, I, 8)[-1]
    assert intercept_8[column_7[[0, -1]]].max() * cfg.n_defenders < 0.5


def test_transport_keeps_order_and_follows_thinned_rows():
    """Two intruder rows far apart (0 and 15 of 16, masses 3:1): the 8 defenders split 6:2 in one
    step and never cross; the parts of each row meet it 8 steps on and then move with it (left a
    column a step, still engaged every step)."""
    n = 16
    cfg = AllocConfig(grid_size=n, n_defenders=8, n_intruders=1600, max_steps=n, team_sizes="lattice")
    D, I = np.zeros(n * n), np.zeros(n * n)
    D[8 * n] = 1.0
    I[n - 1], I[n * n - 1] = 0.3, 0.1
    path = _run_moves(Transport(cfg), cfg, D, I, 11)
    up, down = cells(n, (7, 1), (9, 1))
    assert path[0][up] * 8 == pytest.approx(6.0) and path[0][down] * 8 == pytest.approx(2.0)
    for k, col in ((8, 7), (9, 6), (11, 4)):  # met at step 8 in column 7, then escorted
        top, bottom = cells(n, (0, col), (15, col))
        assert path[k - 1][top] * 8 == pytest.approx(6.0) and path[k - 1][bottom] * 8 == pytest.approx(2.0)


def test_mmr_splits_by_the_marginal_rule():
    """Two coming intruder cells next to 4 defenders, intruder masses 0.75 and 0.25, a concave curve
    removed(n) = 1 - 2^-n (gains per defender 1/2, 1/4, 1/8, ...). Marginal returns: A 0.375,
    0.1875, 0.094, 0.047; B 0.125, 0.0625: greedy takes A, A, B, A: 3 defenders to A, 1 to B."""
    cfg = AllocConfig(grid_size=3, n_defenders=4, n_intruders=4, team_sizes="exact", c_capture=0.0)
    client = curve_client(cfg, lambda p, e: 1 - 0.5 ** p)
    D, I = density(3, c4=1.0), density(3, c2=0.75, c8=0.25)  # they advance to (0, 1) and (2, 1)
    planner = MaxMarginalReturn(cfg, client)
    env = env_at(cfg, client, D, I)
    D1 = realised(env, planner.predict(obs_of(D, I))[0])
    a, b = cells(3, (0, 1), (2, 1))
    assert D1[a] * 4 == pytest.approx(3, abs=0.01) and D1[b] * 4 == pytest.approx(1, abs=0.01)
    _, reward, _, _, info = env.step(planner.predict(obs_of(D, I))[0])
    assert info["eliminated_step"] == pytest.approx(0.75 * (1 - 1 / 8) + 0.25 * (1 - 1 / 2))


def test_mmr_does_not_stall_on_a_flat_curve():
    """Teams below 8 catch nobody, 8 or more catch 7/8: one more defender returns nothing, yet MMR
    steps straight to the 8-defender game (the next distinct game with a return)."""
    cfg = cfg_of(n_defenders=10, c_capture=0.0)
    client = curve_client(cfg, lambda p, e: 0.875 if p >= 8 else 0.0)
    D, I = density(3, c4=1.0), density(3, c2=0.4, c8=0.1)
    env = env_at(cfg, client, D, I)
    _, _, _, _, info = env.step(MaxMarginalReturn(cfg, client).predict(obs_of(D, I))[0])
    assert info["eliminated_step"] == pytest.approx(0.4 * 0.875)


# ----------------------------------------------------------------------------- receding horizon: exactness
def one_step_value(cfg, client, cell, I1, count):
    """The one-step reward terms of one engaged cell: c_distribution * removed mass + c_capture * score."""
    n_p, n_e = team_sizes(cfg, np.array([count / cfg.n_defenders]), np.array([I1[cell]]))
    if n_p[0] == 0 or I1[cell] <= cfg.engage_min_mass:
        return 0.0
    v = client.get_many([(int(n_p[0]), int(n_e[0]))])[0]
    return I1[cell] * (cfg.c_distribution * v.frac_captured_tau + cfg.c_capture * v.capture_score_tau)


def test_rh_one_step_equals_brute_force_over_chunks():
    """2x2, 4 defenders as single chunks on two cells (every cell neighbours every other), exact team
    sizes, intruders on two rows: RH with H = 1 reaches the best of all 4^4 chunk assignments, and
    the env pays it that reward."""
    cfg = AllocConfig(grid_size=2, n_defenders=4, n_intruders=6, team_sizes="exact", c_capture=1.5,
                      breach_penalty=1.0)
    client = curve_client(cfg, lambda p, e: min(1.0, 0.25 + 0.7 * p / (p + e) - 0.01 * e))
    D, I = as_observed(density(2, c0=0.5, c3=0.5), density(2, c1=0.5, c3=0.3))
    I1, breach = advance_intruders(I, 2, 0.0)
    best = -np.inf  # the defenders, two in cell 0 and two in cell 3, may each go to any cell
    for dests in itertools.product(range(4), repeat=4):
        counts = np.bincount(dests, minlength=4)
        gained = sum(one_step_value(cfg, client, c, I1, counts[c]) for c in range(4))
        best = max(best, gained)
    best_reward = -cfg.c_distribution * I1.sum() + best - cfg.breach_penalty * breach
    planner = RecedingHorizon(cfg, client, horizon=1)
    action, _ = planner.predict(obs_of(D, I))
    assert planner.last["reward"] == pytest.approx(best_reward, abs=1e-12)
    _, reward, _, _, _ = env_at(cfg, client, D, I).step(action)
    assert reward == pytest.approx(best_reward, abs=1e-12)


def choice_and_without(net, rng):
    """A random choice of levels at net's targets with target i engaged, and without it: (choice, without, i)."""
    choice = np.where(rng.random(net["T"]) < 0.5, rng.integers(1, net["m"] + 1, net["T"]), 0)
    i = int(rng.integers(net["T"]))
    choice[i] = int(rng.integers(1, net["m"] + 1))
    without = choice.copy()
    without[i] = 0
    return choice, without, i


def fillable_levels(cfg, env, targets, x):
    """The lowest counts of each combination of levels at targets that a flow of the counts x fills (an LP)."""
    L = levels(cfg)
    lo = np.concatenate([[0.0], L.lo])
    hi = np.concatenate([[L.zero_hi], np.where(np.isfinite(L.hi), L.hi, 1e9)])
    A_eq = np.zeros((cfg.grid_size ** 2, len(env.src)))
    A_eq[env.src, np.arange(len(env.src))] = 1.0
    into = np.zeros((len(targets), len(env.src)))
    for i, t in enumerate(targets):
        into[i, env.dst == t] = 1.0
    for combo in itertools.product(range(len(lo)), repeat=len(targets)):
        combo = np.array(combo)
        if lo[combo].sum() > x.sum():  # more than all the defenders: no flow fills it
            continue
        res = linprog(np.zeros(len(env.src)), A_ub=np.vstack([into, -into]),
                      b_ub=np.concatenate([hi[combo], -lo[combo]]), A_eq=A_eq, b_eq=x, bounds=(0, None),
                      method="highs")
        if res.status == 0:
            yield lo[combo]


def brute_force_levels(cfg, client, D, I):
    """The one-step optimum over the levels: every combination of levels at the coming intruder cells,
    kept when an LP finds flows (each cell's mass over its moves) filling every range."""
    env = SwarmAllocationEnv(cfg, client=client)
    I1, breach = advance_intruders(I, cfg.grid_size, cfg.vertical_drift)
    targets = np.flatnonzero(I1 > cfg.engage_min_mass)
    best = -np.inf
    for lowest in fillable_levels(cfg, env, targets, D * cfg.n_defenders):
        best = max(best, sum(one_step_value(cfg, client, t, I1, count) for t, count in zip(targets, lowest)))
    return -cfg.c_distribution * I1.sum() + best - cfg.breach_penalty * breach


@pytest.mark.parametrize("case", range(3))
def test_rh_one_step_equals_brute_force_over_levels(case, rng):
    """3x3, 6 defenders on the lattice over a few cells, three coming intruder cells: RH with
    H = 1 reaches the best combination of levels that some flow can fill, and the env pays it."""
    cfg = cfg_of(n_defenders=6, c_capture=1.5)
    client = curve_client(cfg, lambda p, e: min(1.0, 0.1 + 0.8 * p / (p + e)))
    D = np.zeros(9)
    D[rng.choice(9, 3, replace=False)] = rng.dirichlet(np.ones(3))
    I = np.zeros(9)
    I[[[1, 2, 5], [2, 5, 8], [1, 4, 7]][case]] = rng.dirichlet(np.ones(3)) * 0.9
    D, I = as_observed(D, I)
    best = brute_force_levels(cfg, client, D, I)
    planner = RecedingHorizon(cfg, client, horizon=1)
    action, _ = planner.predict(obs_of(D, I))
    assert planner.last["reward"] == pytest.approx(best, abs=1e-9)
    env = env_at(cfg, client, D, I)
    assert env.step(action)[1] == pytest.approx(best, abs=1e-9)


@pytest.mark.parametrize("drift", [0.0, 0.25])
def test_rh_values_one_engagement_exactly_given_the_others(drift, rng):
    """5x5 over the whole approach, a plan engaging some targets: a level's value in the program
    (linearised around the plan without that engagement) is exactly what the env's reward over
    the horizon gains from adding it, when the curve does not depend on n_e (so the engagement
    changes no later game; its shares are multiples of 1/64, which every n_e's games represent)."""
    cfg = AllocConfig(grid_size=5, n_defenders=100, n_intruders=50, team_sizes="lattice", c_capture=1.5,
                      breach_penalty=2.0, vertical_drift=drift, max_steps=16)
    client = curve_client(cfg, lambda p, e: round(64 * (1 - 0.7 ** p)) / 64)
    D, I = density(5), np.zeros(25)
    D[10] = 1.0
    I[[4, 9, 14, 19, 24]] = rng.dirichlet(np.ones(5))
    planner = RecedingHorizon(cfg, client)
    H = planner.plan_horizon(I)
    assert H == 5
    net = planner.network(D * 100, I, H)
    for _ in range(5):
        choice, without, i = choice_and_without(net, rng)
        with_reward = planner.simulate(net, I, H, choice)[0]
        reward, rho, score = planner.simulate(net, I, H, without)
        V = planner.values(net, *planner.nominal(I, H, rho, score))
        assert with_reward - reward == pytest.approx(V[i, choice[i]], rel=1e-9, abs=1e-12)


def test_rh_plans_ahead():
    """8x8, 800 v 400 from the start: the first plan spans the whole approach (8 steps, until the
    intruders would breach) and the episode eliminates everything."""
    cfg = AllocConfig(grid_size=8, n_defenders=800, n_intruders=400, c_capture=1.5, team_sizes="lattice",
                      max_steps=16)
    client = curve_client(cfg)
    env = SwarmAllocationEnv(cfg, client=client)
    obs, _ = env.reset(seed=1000)
    planner = RecedingHorizon(cfg, client)
    planner.predict(obs)
    assert planner.last["horizon"] == 8
    while True:
        obs, _, term, trunc, info = env.step(planner.predict(obs)[0])
        if term or trunc:
            break
    assert info["eliminated"] > 0.99


# ----------------------------------------------------------------------------- every planner, any state
def random_state(rng, n):
    D = rng.dirichlet(np.ones(n * n) * 0.3)
    I = np.zeros(n * n)
    k = rng.integers(1, n * n)
    I[rng.choice(n * n, k, replace=False)] = rng.dirichlet(np.ones(k)) * rng.uniform(0.05, 1)
    return D, I


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("name", ALL)
@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), action_map=st.sampled_from(["softmax", "shifted"]),
       drift=st.sampled_from([0.0, 0.25]))
def test_moves_are_feasible(name, n, seed, action_map, drift):
    """Random states: the action is finite, in [-1, 1], of the action space's shape, and the env's
    D' = T D puts mass only on feasible moves (at most one king move) and sums to 1."""
    rng = np.random.default_rng(seed)
    cfg = AllocConfig(grid_size=n, n_defenders=100, n_intruders=50, team_sizes="lattice", action_map=action_map,
                      vertical_drift=drift)
    client = curve_client(cfg)
    D, I = random_state(rng, n)
    planner = make_allocator(name, cfg, client)
    p = planner.probabilities(D, I)
    assert np.all(p >= 0) and np.allclose(np.add.reduceat(p, planner.start), 1.0)
    action, _ = planner.predict(obs_of(D, I))
    env = env_at(cfg, client, D, I)
    assert action.shape == env.action_space.shape and action.dtype == np.float32
    assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1)
    T = env.transition_matrix(action)
    far = planner.cheb > 1
    assert np.all(T[far.T] == 0)
    np.testing.assert_allclose(T.sum(axis=0), 1.0)
    assert realised(env, action).sum() == pytest.approx(D.sum())


@pytest.mark.parametrize("name", ALL)
def test_deterministic(name, real_client):
    """Real (small) games: the same obs twice gives the identical action, and so does a fresh planner."""
    cfg = cfg_of(c_capture=1.5)
    env = SwarmAllocationEnv(cfg, client=real_client)
    obs, _ = env.reset(seed=3)
    first = make_allocator(name, cfg, real_client)
    for _ in range(3):
        a1, _ = first.predict(obs)
        a2, _ = first.predict(obs)
        a3, _ = make_allocator(name, cfg, real_client).predict(obs)
        assert np.array_equal(a1, a2) and np.array_equal(a1, a3)
        obs, _, term, trunc, _ = env.step(a1)
        if term or trunc:
            break


def test_planners_beat_the_swap_on_real_games(real_client):
    """Real (small) games, one episode each: every planner eliminates intruders, greedy_nearest's swap
    on 3x3 aside."""
    cfg = cfg_of(c_capture=1.5)
    env = SwarmAllocationEnv(cfg, client=real_client)
    for name in ALL:
        planner = make_allocator(name, cfg, real_client)
        obs, _ = env.reset(seed=5)
        while True:
            obs, _, term, trunc, info = env.step(planner.predict(obs)[0])
            if term or trunc:
                break
        assert info["eliminated"] > 0.5, name


# ----------------------------------------------------------------------------- bad options
@pytest.mark.parametrize("name, options, field", [
    ("receding_horizon", {"horizon": 0}, "horizon"),
    ("receding_horizon", {"horizon": -2}, "horizon"),
    ("receding_horizon", {"horizon": 1.5}, "horizon"),
    ("receding_horizon", {"horizon": True}, "horizon"),
    ("receding_horizon", {"iterations": 0}, "iterations"),
    ("receding_horizon", {"rounds": "2"}, "rounds"),
    ("receding_horizon", {"time_limit": math.inf}, "time_limit"),
    ("receding_horizon", {"estimates": "yes"}, "estimates"),
    ("receding_horizon", {"horizont": 3}, "horizont"),
    ("mmr", {"chunk": 0}, "chunk"),
    ("mmr", {"chunk": math.nan}, "chunk"),
    ("mmr", {"speed": 1}, "speed"),
    ("intercept", {"ties": "random"}, "ties"),
    ("intercept", {"horizon": 2}, "horizon"),
    ("transport", {"power": 0}, "power"),
    ("transport", {"power": math.inf}, "power"),
    ("transport", {"min_count": -1}, "min_count"),
    ("transport", {"ties": "largest"}, "ties"),
    ("subregions", {"regions": 0}, "regions"),
    ("subregions", {"regions": 4}, "regions"),  # more bands than the 3 rows
    ("subregions", {"planner": "subregions"}, "planner"),
    ("subregions", {"planner": "spread_evenly"}, "planner"),
    ("subregions", {"options": 3}, "options"),
    ("subregions", {"options": {"horizont": 2}}, "horizont"),
    ("subregions", {"workers": 0}, "workers"),
    # sizes bounded before the work: each iteration or round is a program solved every step
    ("receding_horizon", {"iterations": 100000}, "iterations must be an integer from 1 to 100"),
    ("receding_horizon", {"rounds": 101}, "rounds must be an integer from 1 to 100"),
    ("minimax", {"iterations": 100000}, "iterations must be an integer from 1 to 100"),
])
def test_bad_options_are_one_line(name, options, field):
    cfg = cfg_of()
    with pytest.raises(ConfigError) as e:
        make_allocator(name, cfg, curve_client(cfg), **options)
    message = str(e.value)
    assert "\n" not in message and message.startswith(name) and field in message


@pytest.mark.parametrize("name", allocator_names("planner"))
def test_the_suite_check_refuses_unknown_options(name):
    """farm.studies.suite binds planner_options to the class's signature: an unknown one fails there."""
    with pytest.raises(TypeError, match="bogus"):
        inspect.signature(allocator_entry(name).make).bind(None, None, bogus=1)
    inspect.signature(allocator_entry(name).make).bind(None, None)


def test_clients_and_observations_refused():
    cfg = cfg_of()
    for name in ("mmr", "receding_horizon"):
        with pytest.raises(ConfigError, match=f"^{name}: needs a capture-time client"):
            make_allocator(name, cfg, None)
    Intercept(cfg, None)  # needs none
    with pytest.raises(InputError, match=r"obs: expected shape \(18,\)"):
        Intercept(cfg).predict(np.zeros(17, dtype=np.float32))
    with pytest.raises(InputError, match="obs"):
        Intercept(cfg).predict(np.full(18, np.nan, dtype=np.float32))


# ----------------------------------------------------------------------------- sub-regions
def _bands_by_hand(cfg, client, D, I, bands, inner="receding_horizon", shares=None, **options):
    """Sub-regions' plan computed the slow, obvious way: each band's rows masked, its share of
    the force by its intruder mass, the inner planner made afresh per band, plans mixed by share.
    shares: the bands' shares to use (default: computed here). A planner's plan jumps where a
    count crosses a level's threshold, so a share that differs in its last bit (a sum taken in
    another order) can move a plan by 0.1: the join is checked on the planner's own shares, and
    the shares apart from it."""
    n = cfg.grid_size
    rows = np.arange(n * n) // n
    mass = np.array([I[np.isin(rows, band)].sum() for band in bands])
    shares = mass / mass.sum() if shares is None else shares
    p = 0.0
    for band, share in zip(bands, shares):
        if share > 0:
            planner = make_allocator(inner, cfg, client, **options)
            p = p + share * planner.probabilities(D * share, np.where(np.isin(rows, band), I, 0.0))
    return p


@pytest.mark.parametrize("inner", ["intercept", "mmr", "receding_horizon"])
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
@example(seed=73164)
def test_subregions_join_the_bands_plans_by_their_shares(inner, seed):
    """On 6 x 6 in 3 bands of 2 rows: the shares are the bands' intruder mass over the whole, and
    the plan is each band's inner plan (its rows' intruders, its share of every cell's defenders)
    mixed by the shares, as computed by hand; each cell's probabilities sum to 1. (Seed 73164 is
    a state where a reference share 1e-17 off the planner's moved receding_horizon's plan by 0.105.)"""
    rng = np.random.default_rng(seed)
    cfg = AllocConfig(grid_size=6, n_defenders=100, n_intruders=50, team_sizes="lattice", vertical_drift=0.25)
    client = curve_client(cfg)
    D, I = random_state(rng, 6)
    planner = make_allocator("subregions", cfg, client, regions=3, planner=inner)
    bands = [[0, 1], [2, 3], [4, 5]]
    rows = np.arange(36) // 6
    mass = np.array([I[np.isin(rows, band)].sum() for band in bands])
    np.testing.assert_allclose(planner.shares(I), mass / mass.sum(), rtol=1e-12)
    p = planner.probabilities(D, I)
    np.testing.assert_allclose(p, _bands_by_hand(cfg, client, D, I, bands, inner, shares=planner.shares(I)), atol=1e-12)
    assert np.allclose(np.add.reduceat(p, planner.start), 1.0)
    assert sum(planner.last["shares"]) == pytest.approx(1.0)


def test_subregions_of_one_band_or_one_band_with_intruders_is_the_inner_planner():
    """One band is the whole map; and with every intruder in one band, that band gets the whole
    force and the whole problem: the inner planner's plan exactly."""
    cfg = AllocConfig(grid_size=6, n_defenders=100, n_intruders=50, team_sizes="lattice")
    client = curve_client(cfg)
    rng = np.random.default_rng(7)
    D, I = random_state(rng, 6)
    whole = make_allocator("receding_horizon", cfg, client)
    np.testing.assert_array_equal(make_allocator("subregions", cfg, client, regions=1).probabilities(D, I),
                                  whole.probabilities(D, I))
    I_top = np.where(np.arange(36) < 12, I, 0.0)  # rows 0 and 1 only: band 0 of 3
    planner = make_allocator("subregions", cfg, client, regions=3)
    np.testing.assert_array_equal(planner.probabilities(D, I_top), whole.probabilities(D, I_top))
    assert planner.last["shares"] == [1.0, 0.0, 0.0]
    assert make_allocator("subregions", AllocConfig(grid_size=16), client).regions == 2  # bands of at most 8 rows
