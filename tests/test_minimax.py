"""The `minimax` planner (farm.alloc.allocators.planners.minimax, docs/model.md section 7) against brute force.

Hand-made capture curves (test_planners.curve_client) on small grids, so that every defender
level and every pure routing of the intruders can be enumerated.
"""

import itertools
import math

import numpy as np
import pytest
from test_planners import choice_and_without, cfg_of, curve_client, env_at, fillable_levels, obs_of, realised

from farm.alloc import AllocConfig
from farm.alloc.game.dynamics import Layout, step
from farm.alloc.game.model import EngagementModel, route_intruders_many, team_sizes
from farm.alloc.allocators import make_allocator
from farm.alloc.allocators.planners import Minimax
from farm.core.errors import ConfigError


def falling(n_p, n_e):
    """A curve whose removed share falls as n_e grows (merging pays the intruders)."""
    return min(1.0, 0.95 * n_p / (n_p + 0.4 * n_e))


def pure_routings(n, I):
    """Every pure routing of the cells of I holding mass outside column 0: (up, down) lists of (N^2,) float64."""
    cells = [c for c in range(n * n) if I[c] > 1e-6 and c % n > 0]
    options = [[d for d in (-1, 0, 1) if 0 <= c // n + d < n] for c in cells]
    out = []
    for choice in itertools.product(*options):
        up, down = np.zeros(n * n), np.zeros(n * n)
        for c, d in zip(cells, choice, strict=True):
            up[c], down[c] = d == -1, d == 1
        out.append((up, down))
    return out


def eliminated(cfg, client, I1, count):
    """The mass one step's games eliminate: I1 the intruders after their move, count each cell's defenders."""
    n_p, n_e = team_sizes(cfg, count / cfg.n_defenders, I1)
    on = (n_p >= 1) & (I1 > cfg.engage_min_mass)
    if not on.any():
        return 0.0
    removed = [_removed(client, p, e) for p, e in zip(n_p[on].tolist(), n_e[on].tolist(), strict=True)]
    return float(sum(m * r for m, r in zip(I1[on], removed, strict=True)))


_SEEN: dict = {}


def _removed(client, n_p, n_e):
    """The client's frac_captured_tau of one game, asked once per (client, n_p, n_e)."""
    key = (id(client), n_p, n_e)
    if key not in _SEEN:
        _SEEN[key] = client.get_many([(n_p, n_e)])[0].frac_captured_tau
    return _SEEN[key]


def brute_force_maximin(cfg, client, D, I):
    """max over the level combinations some flow can fill at the intruders' possible next cells (those
    the defenders can reach), of the min over the intruders' pure routings of the mass eliminated
    this step."""
    n, n2 = cfg.grid_size, cfg.grid_size ** 2
    env = env_at(cfg, client, D, I)
    routings = pure_routings(n, I)
    landed = [route_intruders_many(I[None], n, u[None], d[None])[0][0] for u, d in routings]
    near = np.array([[max(abs(a // n - b // n), abs(a % n - b % n)) <= 1 for b in range(n2)] for a in range(n2)])
    reach = near[D > 0].any(axis=0)  # the cells the defenders can be at after one move
    targets = np.flatnonzero((np.max(landed, axis=0) > cfg.engage_min_mass) & reach)
    best = -np.inf
    for lowest in fillable_levels(cfg, env, targets, D * cfg.n_defenders):
        count = np.zeros(n2)
        count[targets] = lowest
        best = max(best, min(eliminated(cfg, client, I1, count) for I1 in landed))
    return best, routings


@pytest.mark.parametrize("case", range(4))
def test_one_step_equals_brute_force_maximin(case, rng):
    """3x3, 3 defenders on the lattice over a few cells, intruders on two or three cells: with H = 1
    the planner's worst case is the brute-force maximin over the defenders' levels and the
    intruders' pure routings, and stepping the env with its action under every pure routing
    (the follower's replies) eliminates at least that, the worst exactly that."""
    cfg = cfg_of(n_defenders=3, n_intruders=12)
    client = curve_client(cfg, falling)
    D = np.zeros(9)
    D[rng.choice(9, 2, replace=False)] = rng.dirichlet(np.ones(2))
    I = np.zeros(9)
    I[[[2, 5, 8], [1, 4], [4, 5, 8], [1, 2, 5]][case]] = 0.3 + 0.7 * rng.random(3)[: [3, 2, 3, 3][case]] / 3
    D, I = D.astype(np.float32).astype(np.float64), I.astype(np.float32).astype(np.float64)
    best, routings = brute_force_maximin(cfg, client, D, I)
    planner = Minimax(cfg, client, horizon=1, robustness=1.0)
    action, _ = planner.predict(obs_of(D, I))
    assert planner.last["worst"] == pytest.approx(best, abs=1e-9)
    layout, model = Layout(3), EngagementModel(cfg, client)
    got = [step(layout, cfg, model, D[None], I[None], action[None].astype(np.float64),
                lambda D1, I0, u=u, d=d: (u[None], d[None])).eliminated[0] for u, d in routings]
    assert min(got) == pytest.approx(best, abs=1e-9)


def test_the_first_step_plays_the_planned_games(rng):
    """5x5 over the whole approach: the env's D' (the action through the softmax map) plays, at
    every cell the intruders can reach next, the game of the level the kept plan chose there."""
    cfg = AllocConfig(grid_size=5, n_defenders=8, n_intruders=100, team_sizes="lattice", c_capture=1.5,
                      max_steps=16)
    client = curve_client(cfg, falling)
    for _ in range(3):
        D = rng.dirichlet(np.ones(25) * 0.3)
        I = np.zeros(25)
        I[np.arange(5) * 5 + rng.integers(2, 5)] = rng.dirichlet(np.ones(5)) * 0.8
        planner = Minimax(cfg, client)
        action, _ = planner.predict(obs_of(D, I))
        planned = planner.last["levels"]
        assert planned is not None and planner.last["horizon"] >= 2
        D1 = realised(env_at(cfg, client, D, I), action)
        cone = planner.cone(I, 1)[1]
        n_p = team_sizes(cfg, D1, np.ones(25))[0]
        want = np.concatenate([[0], planner.levels.sizes])[planned[1]]
        assert np.array_equal(n_p[cone], want[cone])
        assert D1.sum() == pytest.approx(D.sum())


def test_replies_find_the_worst_routing_sequence_of_a_plan(rng):
    """3x3, a fixed plan of levels over the next two steps: a beam as wide as the routings finds the
    worst of all pure routing sequences (enumerated, each step's games the env's), and the
    planner's simulated value of a reply is what the env's steps give it."""
    cfg = cfg_of(n_defenders=4, n_intruders=40)
    client = curve_client(cfg, falling)
    planner = Minimax(cfg, client, beam=200)
    layout, model = Layout(3), EngagementModel(cfg, client)
    sizes = np.concatenate([[0.0], planner.levels.sizes.astype(float)])
    I = np.zeros(9)
    I[[2, 5, 8]] = rng.dirichlet(np.ones(3))
    plan = np.zeros((3, 9), dtype=np.int64)
    plan[1, [1, 4, 7]] = rng.integers(0, 4, 3)
    plan[2, [0, 3, 6]] = rng.integers(0, 4, 3)
    D_plan = sizes[plan] / cfg.n_defenders  # the defenders after each step's move, at the plan's counts

    def env_steps(routes):  # the env's steps from I, the defenders moved to the plan's densities
        total, I0 = 0.0, I[None]
        for t, (u, d) in enumerate(routes, start=1):
            r = step(layout, cfg, model, D_plan[t][None], I0, stay_action(layout)[None],
                     lambda D1, I_, u=u, d=d: (u[None], d[None]))
            total, I0 = total + r.eliminated[0], r.I
        return total, I0[0]

    worst = np.inf
    for first in pure_routings(3, I):
        _, after = env_steps([first])
        for second in pure_routings(3, after):
            worst = min(worst, env_steps([first, second])[0])
    up, down, values = planner.replies(plan, D_plan, I, 2)
    assert values.min() == pytest.approx(worst, abs=1e-12)
    for k in range(len(values)):
        assert env_steps([(up[k, 0], down[k, 0]), (up[k, 1], down[k, 1])])[0] == pytest.approx(values[k], abs=1e-12)


def stay_action(layout):
    """The action that keeps every cell's defenders where they are (up to the softmax map's leak)."""
    a = -np.ones(len(layout.src))
    a[layout.src == layout.dst] = 1.0
    return a


@pytest.mark.parametrize("objective", ["eliminated", "reward"])
def test_level_values_are_exact_for_one_change(objective, rng):
    """5x5 over the approach, a curve that does not depend on n_e: a level's value in a course,
    linearised around a plan without that engagement, is exactly what the course's simulated
    value gains from adding it (as receding_horizon's values)."""
    cfg = AllocConfig(grid_size=5, n_defenders=100, n_intruders=50, team_sizes="lattice", c_capture=1.5,
                      breach_penalty=2.0, max_steps=16)
    client = curve_client(cfg, lambda p, e: round(64 * (1 - 0.7 ** p)) / 64)
    planner = Minimax(cfg, client, objective=objective)
    I = np.zeros(25)
    I[[4, 9, 14, 19, 24]] = rng.dirichlet(np.ones(5))
    x = np.zeros(25)
    x[10] = 100.0
    net = planner.flow_network(x, planner.cone(I, 5))
    up, down = planner.initial_courses(I, 5, first=False)
    for _ in range(5):
        choice, without, i = choice_and_without(net, rng)
        plan_with, plan_without = (np.zeros((6, 25), dtype=np.int64) for _ in range(2))
        plan_with[net["targets"][:, 0], net["targets"][:, 1]] = choice
        plan_without[net["targets"][:, 0], net["targets"][:, 1]] = without
        W, const = planner.level_values(net, plan_without, up, down, I)
        v_with = planner.simulate(plan_with, up, down, I)[0]
        v_without = planner.simulate(plan_without, up, down, I)[0]
        np.testing.assert_allclose(const + W[:, np.arange(net["T"]), without].sum(axis=1), v_without, atol=1e-12)
        np.testing.assert_allclose(v_with - v_without, W[:, i, choice[i]], rtol=1e-9, atol=1e-12)


def test_robustness_traces_the_trade_off():
    """3x3, 4 defenders v 40 intruders on three rows, defenders at the base: the worst case the
    plan holds does not fall and its drift value does not rise as the robustness grows."""
    cfg = cfg_of(n_defenders=4, n_intruders=40, c_capture=1.5)
    client = curve_client(cfg, falling)
    D, I = np.zeros(9), np.zeros(9)
    D[3], I[[2, 5, 8]] = 1.0, [0.5, 0.3, 0.2]
    seen = []
    for r in (0.0, 0.5, 1.0):
        planner = Minimax(cfg, client, robustness=r)
        planner.predict(obs_of(D, I))
        seen.append((planner.last["worst"], planner.last["drift"]))
    assert all(a[0] <= b[0] + 1e-9 and a[1] >= b[1] - 1e-9 for a, b in zip(seen, seen[1:], strict=False))
    assert seen[-1][0] > seen[0][0]


def test_deterministic():
    """The same obs twice, or to a fresh planner, gives the identical action, over an episode."""
    cfg = cfg_of(n_defenders=6, n_intruders=30, c_capture=1.5)
    client = curve_client(cfg, falling)
    env = env_at(cfg, client, np.eye(9)[3], np.zeros(9))
    obs, _ = env.reset(seed=3)
    first = make_allocator("minimax", cfg, client)
    for _ in range(4):
        a1, _ = first.predict(obs)
        a2, _ = first.predict(obs)
        a3, _ = make_allocator("minimax", cfg, client).predict(obs)
        assert np.array_equal(a1, a2) and np.array_equal(a1, a3)
        obs, _, term, trunc, _ = env.step(a1)
        if term or trunc:
            break


@pytest.mark.parametrize("options, field", [
    ({"horizon": 0}, "horizon"),
    ({"robustness": 1.5}, "robustness"),
    ({"robustness": -0.1}, "robustness"),
    ({"robustness": math.nan}, "robustness"),
    ({"robustness": True}, "robustness"),
    ({"objective": "return"}, "objective"),
    ({"iterations": 0}, "iterations"),
    ({"courses": -1}, "courses"),
    ({"routings": 0}, "routings"),
    ({"beam": 2.5}, "beam"),
    ({"branch_levels": "all"}, "branch_levels"),
    ({"replies": ["nobody"]}, "replies"),
    ({"replies": "fewest_ahead"}, "replies"),
    ({"rounds": 0}, "rounds"),
    ({"time_limit": 0}, "time_limit"),
    ({"estimates": 1}, "estimates"),
    ({"horizont": 3}, "horizont"),
])
def test_bad_options_are_one_line(options, field):
    cfg = cfg_of()
    with pytest.raises(ConfigError) as e:
        make_allocator("minimax", cfg, curve_client(cfg), **options)
    message = str(e.value)
    assert "\n" not in message and message.startswith("minimax") and field in message


def test_needs_a_client():
    with pytest.raises(ConfigError, match="^minimax: needs a capture-time client"):
        make_allocator("minimax", cfg_of(), None)
