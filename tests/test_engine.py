"""The batched engine against the slow reference (tests/shapely_reference.py), analytic
cases and invariants of docs/model.md."""

import math

import numpy as np
import pytest
from conftest import HEXAGON, TRIANGLE, points_in
from shapely_reference import reference_game, reference_velocities

from workers import InputError, simulate_games
from workers.engine import step_velocities
from workers.geometry import voronoi_cells

PURSUERS = ["area_min", "pure_pursuit"]
EVADERS = ["constant_area", "centroid", "target", "area_max"]
PAIRS = [(pp, ep) for pp in PURSUERS for ep in EVADERS]
SIZES = [(1, 1), (3, 1), (5, 1), (4, 3)]


def assert_game_invariants(res):
    """invariants of docs/model.md of recorded games without an exit point, checked on the paths
    themselves: capture steps are re-derived from the pursuer-evader distances."""
    dt, r_c = res.dt, res.capture_radius
    P, E = res.pursuer_paths, res.evader_paths
    n_steps = math.floor(res.t_max / dt + 1e-9)
    assert np.all(res.escape_step == -1)
    caught = res.capture_step >= 0
    # capture times are whole steps of the game, within [0, t_max]
    np.testing.assert_array_equal(res.capture_times[caught], res.capture_step[caught] * dt)
    assert np.all(np.isnan(res.capture_times[~caught]))
    assert np.all((res.capture_step[caught] >= 0) & (res.capture_times[caught] <= res.t_max))
    # a game ends when its last evader is caught, else at floor(t_max / dt)
    expected_steps = np.where(caught.all(axis=1), res.capture_step.max(axis=1), n_steps)
    np.testing.assert_array_equal(res.steps, expected_steps)
    # everyone stays in the arena and moves at most v_max * dt a step
    assert res.arena.contains(P).all() and res.arena.contains(E).all()
    assert np.all(np.linalg.norm(np.diff(P, axis=0), axis=-1) <= res.pursuer_speed * dt * (1 + 1e-9))
    assert np.all(np.linalg.norm(np.diff(E, axis=0), axis=-1) <= res.evader_speed * dt * (1 + 1e-9))
    for b in range(res.n_games):
        for i in range(E.shape[2]):
            frames = slice(0, res.steps[b] + 1)
            dist = np.hypot(P[frames, b, :, 0] - E[frames, b, i, None, 0],
                            P[frames, b, :, 1] - E[frames, b, i, None, 1]).min(axis=1)
            below = np.flatnonzero(dist < r_c)
            assert res.capture_step[b, i] == (below[0] if len(below) else -1), (b, i)
            if caught[b, i]:  # a caught evader stays where it was caught
                k = res.capture_step[b, i]
                assert np.all(E[k:, b, i] == E[k, b, i])


@pytest.mark.parametrize("pp", PURSUERS)
@pytest.mark.parametrize("ep", EVADERS)
def test_velocities_match_reference_along_trajectories(pp, ep, rng):
    """Every recorded state of random games: the engine's controls equal the reference's."""
    for n_p, n_e in SIZES:
        P, E = rng.random((3, n_p, 2)) * 10, rng.random((3, n_e, 2)) * 10
        res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=8.0, record=True)
        frames = res.pursuer_paths.shape[0]
        for frame in range(0, frames, max(7, frames // 40)):  # about 40 states a game, games that run to t_max too
            alive = res.alive_at(frame)
            for b in np.flatnonzero(alive.any(axis=1) & (res.steps >= frame)):
                p, e = res.pursuer_paths[frame, b], res.evader_paths[frame, b]
                up, ue = step_velocities(p[None], e[None], alive[b][None], pursuer_policy=pp, evader_policy=ep)
                rp, re = reference_velocities(p, e, alive[b], pursuer_policy=pp, evader_policy=ep)
                np.testing.assert_allclose(up[0], rp, atol=1e-8)
                np.testing.assert_allclose(ue[0], re, atol=1e-8)


@pytest.mark.slow
@pytest.mark.parametrize("pp", PURSUERS)
@pytest.mark.parametrize("ep", EVADERS)
def test_capture_times_match_reference(pp, ep, rng):
    """Whole games: identical capture times, except where round-off (1e-12 per step)
    is amplified by the game's sensitivity into a few steps' difference."""
    exact, total = 0, 0
    for n_p, n_e in SIZES:
        P, E = rng.random((3, n_p, 2)) * 10, rng.random((3, n_e, 2)) * 10
        ours = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=10.0).capture_times
        ref = np.array([reference_game(P[b], E[b], pursuer_policy=pp, evader_policy=ep, t_max=10.0) for b in range(3)])
        assert np.array_equal(np.isnan(ours), np.isnan(ref))
        both = ~np.isnan(ours)
        assert np.all(np.abs(ours[both] - ref[both]) <= 0.25)
        exact += int(np.sum(ours[both] == ref[both]) + np.sum(~both))
        total += ours.size
    assert exact / total >= 0.8


def test_paper_cases_bit_identical_to_reference(rng):
    for pp, ep, n_p in [("pure_pursuit", "target", 3), ("area_min", "constant_area", 1)]:
        P = np.stack([rng.uniform(3, 5, (5, n_p)), rng.uniform(0, 10, (5, n_p))], -1)
        E = np.stack([rng.uniform(7, 9, (5, 1)), rng.uniform(0, 10, (5, 1))], -1)
        ours = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep).capture_times
        ref = np.array([reference_game(P[b], E[b], pursuer_policy=pp, evader_policy=ep) for b in range(5)])
        assert np.array_equal(ours, ref)


@pytest.mark.parametrize("d", [1.003, 2.347, 5.005])  # away from ties at r_c
def test_stationary_evader_under_pure_pursuit(d):
    """An evader parked on its target is caught at the first step k+1 with d-(k+1)dt < r_c."""
    e = np.array([[[0.0, 5.0]]])
    p = np.array([[[d, 5.0]]])
    res = simulate_games(p, e, pursuer_policy="pure_pursuit", evader_policy="target")
    k1 = next(k for k in range(1, 10_000) if d - k * 0.01 < 0.25)
    assert res.capture_step[0, 0] == k1
    assert res.capture_times[0, 0] == k1 * 0.01


def test_capture_at_start_and_not_captured_is_nan():
    p = np.array([[[5.0, 5.0]], [[1.0, 1.0]]])
    e = np.array([[[5.1, 5.0]], [[9.0, 9.0]]])
    res = simulate_games(p, e, pursuer_policy="pure_pursuit", evader_policy="target", target=(9.0, 9.0), t_max=1.0)
    assert res.capture_times[0, 0] == 0.0
    assert np.isnan(res.capture_times[1, 0])
    assert res.steps[0] == 0 and res.steps[1] == 100


@pytest.mark.parametrize("pp,ep", PAIRS)
def test_evader_within_capture_radius_is_caught_at_t0(pp, ep):
    """Captured at t = 0 iff strictly within r_c of a pursuer: on top of it, inside, or
    just inside; one at exactly r_c (0.25, exact in binary) is not."""
    p = np.array([[[5.0, 5.0], [1.0, 1.0]]])
    e = np.array([[[5.0, 5.0], [5.1, 5.0], [1.0, 1.0 + 0.25 * (1 - 1e-12)], [5.0, 5.25]]])
    res = simulate_games(p, e, pursuer_policy=pp, evader_policy=ep, record=True)
    np.testing.assert_array_equal(res.capture_times[0, :3], [0.0, 0.0, 0.0])
    assert res.capture_step[0, 3] > 0
    # evaders caught at t = 0 never move
    np.testing.assert_array_equal(res.evader_paths[:, 0, :3],
                                  np.broadcast_to(e[0, :3], res.evader_paths[:, 0, :3].shape))
    # a game whose only evaders start caught takes no step
    only = simulate_games(p, e[:, :3], pursuer_policy=pp, evader_policy=ep)
    assert only.steps[0] == 0 and np.all(only.capture_step == 0)


def _line_capture_step(x_p, x_e, goal, vp, ve, dt=0.01, r_c=0.25, n=20_000):
    """First step at which a pure-pursuit pursuer catches a `target` evader on one line,
    in closed form: the evader runs to its goal at ve and stops there; the pursuer runs
    at vp towards it (neither passes the other before the capture)."""
    k = np.arange(n)
    e = x_e + np.sign(goal - x_e) * np.minimum(k * ve * dt, abs(goal - x_e))
    p = x_p + np.sign(x_e - x_p) * k * vp * dt
    gap = np.abs(e - p)
    k1 = int(np.argmax(gap < r_c))
    assert gap[k1] < r_c and np.min(np.abs(gap[: k1 + 1] - r_c)) > 1e-7, "a tie at r_c: pick another case"
    return k1


@pytest.mark.parametrize("x_p,x_e,goal,vp,ve", [
    (1.0, 3.003, 9.9, 1.0, 0.5),    # tail chase, closing at vp - ve
    (1.0, 2.0049, 9.9, 1.0, 0.9),   # slow tail chase
    (0.5, 3.5037, 9.9, 2.0, 1.0),   # faster pursuer
    (1.0037, 3.0071, 9.9, 1.0, 1.0),  # equal speeds: the gap holds until the evader stops on its goal
    (9.0, 4.9987, 9.9, 1.0, 1.0),   # head on, closing at vp + ve
    (9.5, 2.0011, 9.9, 1.5, 0.7),   # head on, unequal speeds
    (2.0, 8.5029, 0.1, 0.8, 0.3),   # leftwards, slower pursuer than usual
])
def test_pure_pursuit_on_a_line_matches_the_closed_form(x_p, x_e, goal, vp, ve):
    p, e = np.array([[[x_p, 5.0]]]), np.array([[[x_e, 5.0]]])
    res = simulate_games(p, e, pursuer_policy="pure_pursuit", evader_policy="target", target=(goal, 5.0),
                         pursuer_speed=vp, evader_speed=ve)
    k1 = _line_capture_step(x_p, x_e, goal, vp, ve)
    assert res.capture_step[0, 0] == k1 and res.capture_times[0, 0] == k1 * 0.01


def _pursuit_ode_capture_time(p0, e0, goal, vp, ve, r_c=0.25):
    """Continuous pure pursuit of an evader running straight at ve: the time the distance
    falls to r_c, by a high-accuracy ODE solve (scipy), before the evader reaches its goal."""
    from scipy.integrate import solve_ivp

    e0, p0 = np.asarray(e0, float), np.asarray(p0, float)
    heading = np.asarray(goal, float) - e0
    arrival = np.linalg.norm(heading) / ve
    heading /= np.linalg.norm(heading)

    def gap(t, p):
        return e0 + ve * t * heading - p

    def caught(t, p):
        return np.linalg.norm(gap(t, p)) - r_c

    caught.terminal, caught.direction = True, -1
    sol = solve_ivp(lambda t, p: vp * gap(t, p) / np.linalg.norm(gap(t, p)), (0.0, arrival), p0,
                    events=caught, rtol=1e-10, atol=1e-12)
    assert len(sol.t_events[0]) == 1, "the evader reaches its goal first: pick another case"
    return sol.t_events[0][0]


@pytest.mark.parametrize("p0,e0,goal,vp,ve", [
    ((2.0, 1.0), (2.0, 5.0), (9.9, 5.0), 1.0, 0.5),  # evader crossing the pursuer's bow
    ((1.0, 8.0), (1.0, 2.0), (9.9, 2.0), 1.0, 0.5),
    ((8.0, 5.0), (2.0, 3.0), (9.9, 3.0), 1.0, 0.6),  # evader running past the pursuer
    ((5.0, 5.0), (5.0, 8.0), (0.1, 8.0), 1.5, 1.0),
    ((1.0, 1.0), (4.0, 1.0), (4.0, 9.9), 1.0, 0.8),
    ((9.0, 9.0), (1.0, 1.0), (9.0, 1.0), 2.0, 1.0),
])
def test_pure_pursuit_of_a_straight_running_evader_matches_the_ode(p0, e0, goal, vp, ve):
    """Euler with dt = 0.01 lags the continuous pursuit by O(dt); the continuous time
    also obeys the closed-form bounds from d/dt (vp r + ve x) = ve^2 - vp^2 (r the
    distance, x its component along the evader's heading, |x| <= r_c at capture)."""
    res = simulate_games(np.array([[p0]]), np.array([[e0]]), pursuer_policy="pure_pursuit", evader_policy="target",
                         target=goal, pursuer_speed=vp, evader_speed=ve)
    t_ode = _pursuit_ode_capture_time(p0, e0, goal, vp, ve)
    t = res.capture_times[0, 0]
    assert -0.01 <= t - t_ode <= 0.03, (t, t_ode)
    heading = np.subtract(goal, e0) / math.dist(goal, e0)
    r0, x0 = math.dist(p0, e0), float(np.dot(np.subtract(e0, p0), heading))
    lo, hi = [(vp * r0 + ve * x0 - (vp + s * ve) * 0.25) / (vp**2 - ve**2) for s in (1, -1)]
    assert lo - 1e-6 <= t_ode <= hi + 1e-6


# The symmetries of the square [0, 10]^2: (point map, velocity map).
SQUARE_SYMMETRIES = {
    "swap_xy": (lambda a: a[..., ::-1], lambda v: v[..., ::-1]),
    "mirror_x": (lambda a: np.stack([10 - a[..., 0], a[..., 1]], -1), lambda v: v * [-1, 1]),
    "mirror_y": (lambda a: np.stack([a[..., 0], 10 - a[..., 1]], -1), lambda v: v * [1, -1]),
    "rotate_90": (lambda a: np.stack([10 - a[..., 1], a[..., 0]], -1), lambda v: np.stack([-v[..., 1], v[..., 0]], -1)),
    "rotate_180": (lambda a: 10 - a, lambda v: -v),
}


@pytest.mark.parametrize("pp,ep", PAIRS)
def test_controls_are_equivariant_under_the_squares_symmetries(pp, ep, rng):
    """Mirror or rotate a state (and the target) with the square: the controls turn with it."""
    P, E = rng.random((20, 4, 2)) * 10, rng.random((20, 3, 2)) * 10
    alive = rng.random((20, 3)) < 0.8
    alive[:, 0] = True
    target = np.array([1.0, 3.0])
    up, ue = step_velocities(P, E, alive, pursuer_policy=pp, evader_policy=ep, target=target)
    for name, (g, lin) in SQUARE_SYMMETRIES.items():
        gp, ge = step_velocities(g(P), g(E), alive, pursuer_policy=pp, evader_policy=ep,
                                  target=np.ascontiguousarray(g(target)))
        np.testing.assert_allclose(gp, lin(up), atol=1e-9, err_msg=name)
        np.testing.assert_allclose(ge, lin(ue), atol=1e-9, err_msg=name)


@pytest.mark.parametrize("pp", PURSUERS)
def test_mirror_symmetric_games_stay_symmetric(pp, rng):
    """Two pursuers mirrored in y = 5 and an evader on that line running along it: the
    whole game stays mirrored, and its mirror image (the same start with the two pursuers
    relabelled) has the same capture times.
    (Cell-following evaders dither about their centroid, which amplifies round-off;
    the target evader does not.)"""
    a = np.stack([rng.uniform(0.5, 4.5, 6), rng.uniform(0.5, 4.5, 6)], -1)
    P = np.stack([a, a * [1, -1] + [0, 10]], 1)
    E = np.stack([rng.uniform(5, 9.5, 6), np.full(6, 5.0)], -1)[:, None]
    res = simulate_games(P, E, pursuer_policy=pp, evader_policy="target", record=True)
    pa, ea = res.pursuer_paths, res.evader_paths
    np.testing.assert_allclose(pa[:, :, 0, 0], pa[:, :, 1, 0], atol=1e-9)
    np.testing.assert_allclose(pa[:, :, 0, 1] + pa[:, :, 1, 1], 10.0, atol=1e-9)
    np.testing.assert_allclose(ea[:, :, 0, 1], 5.0, atol=1e-9)
    swapped = simulate_games(P[:, ::-1], E, pursuer_policy=pp, evader_policy="target")
    np.testing.assert_array_equal(swapped.capture_times, res.capture_times)


def test_swapping_the_axes_swaps_the_game(rng):
    """Pure pursuit of target evaders is computed coordinate-wise symmetrically, so
    the game with x and y exchanged (target too) is the same game, bit for bit."""
    P, E = rng.random((10, 3, 2)) * 10, rng.random((10, 2, 2)) * 10
    kw = dict(pursuer_policy="pure_pursuit", evader_policy="target", t_max=20.0, record=True)
    a = simulate_games(P, E, target=(0.0, 5.0), **kw)
    b = simulate_games(P[..., ::-1], E[..., ::-1], target=(5.0, 0.0), **kw)
    np.testing.assert_array_equal(a.capture_step, b.capture_step)
    np.testing.assert_array_equal(a.pursuer_paths, b.pursuer_paths[..., ::-1])
    np.testing.assert_array_equal(a.evader_paths, b.evader_paths[..., ::-1])


@pytest.mark.parametrize("pp,ep", PAIRS)
@pytest.mark.parametrize("speeds", [(1.0, 1.0), (1.3, 0.8), (0.7, 1.2)])
def test_random_games_keep_the_invariants(pp, ep, speeds, rng):
    P, E = rng.random((4, 3, 2)) * 10, rng.random((4, 2, 2)) * 10
    res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=15.0, record=True,
                         pursuer_speed=speeds[0], evader_speed=speeds[1])
    assert_game_invariants(res)


@pytest.mark.parametrize("pp,ep", PAIRS)
def test_captured_evader_leaves_the_game(pp, ep):
    """Evader 0 is caught at once; the rest of the game is then exactly the game
    without it (no cell, no target, no motion), and, for one pair, the reference's."""
    p = np.array([[[2.0, 5.0], [2.0, 6.0]]])
    e = np.array([[[2.1, 5.0], [8.0, 5.0]]])
    res = simulate_games(p, e, pursuer_policy=pp, evader_policy=ep, record=True)
    solo = simulate_games(p, e[:, 1:], pursuer_policy=pp, evader_policy=ep, record=True)
    assert res.capture_times[0, 0] == 0.0
    np.testing.assert_array_equal(res.evader_paths[:, 0, 0], np.broadcast_to([2.1, 5.0], (len(res.evader_paths), 2)))
    assert res.capture_step[0, 1] == solo.capture_step[0, 0] > 0
    np.testing.assert_array_equal(res.pursuer_paths, solo.pursuer_paths)
    np.testing.assert_array_equal(res.evader_paths[:, :, 1], solo.evader_paths[:, :, 0])
    if (pp, ep) == ("pure_pursuit", "constant_area"):
        ref = reference_game(p[0], e[0], pursuer_policy=pp, evader_policy=ep)
        np.testing.assert_array_equal(res.capture_times[0], ref)


def _areas(res, frame):
    n_p = res.pursuer_paths.shape[2]
    pts = np.concatenate([res.pursuer_paths[frame], res.evader_paths[frame]], axis=1)
    alive = res.alive_at(frame)
    live = np.concatenate([np.ones((res.n_games, n_p), bool), alive], axis=1)
    g, i = np.nonzero(alive)
    area = np.full(alive.shape, np.nan)
    area[g, i] = voronoi_cells(pts, live, g, n_p + i, res.arena).area_centroid()[0]
    return area


@pytest.mark.parametrize("ep", EVADERS)
def test_area_min_never_grows_the_evader_cell(ep, rng):
    """docs/model.md: under area_min the evader's cell is non-increasing for any evader
    policy, up to O(dt^2) per step and jumps when the neighbour set changes."""
    P = np.stack([rng.uniform(3, 5, (6, 3)), rng.uniform(0, 10, (6, 3))], -1)
    E = np.stack([rng.uniform(7, 9, (6, 1)), rng.uniform(0, 10, (6, 1))], -1)
    res = simulate_games(P, E, pursuer_policy="area_min", evader_policy=ep, t_max=6.0, record=True)
    prev = _areas(res, 0)
    growth = []
    for f in range(1, res.pursuer_paths.shape[0]):
        cur = _areas(res, f)
        ok = np.isfinite(prev) & np.isfinite(cur)
        growth.append(np.where(ok, cur - prev, -np.inf).max())
        prev = cur
    growth = np.array(growth)
    # All but the rare neighbour-change steps grow by at most c * dt^2.
    assert np.mean(growth <= 50 * 0.01**2) >= 0.97
    assert np.median(growth) < 0


def test_same_input_same_numbers_and_batch_independence(rng):
    P, E = rng.random((6, 4, 2)) * 10, rng.random((6, 3, 2)) * 10
    a = simulate_games(P, E, t_max=10.0).capture_times
    b = simulate_games(P, E, t_max=10.0).capture_times
    np.testing.assert_array_equal(a, b)
    split = np.concatenate([simulate_games(P[i : i + 1], E[i : i + 1], t_max=10.0).capture_times for i in range(6)])
    np.testing.assert_array_equal(a, split)


@pytest.mark.slow
def test_non_square_arena_game(rng):
    P, E = points_in(HEXAGON, (4, 3), rng), points_in(HEXAGON, (4, 2), rng)
    res = simulate_games(P, E, arena=HEXAGON, t_max=20.0, record=True)
    assert_game_invariants(res)
    ref = np.array([reference_game(P[b], E[b], arena=HEXAGON, t_max=20.0) for b in range(4)])
    assert np.array_equal(np.isnan(res.capture_times), np.isnan(ref))
    both = ~np.isnan(ref)
    assert np.all(np.abs(res.capture_times[both] - ref[both]) <= 0.05)
    assert np.mean(res.capture_times[both] == ref[both]) >= 0.5


@pytest.mark.parametrize("pp,ep", [("area_min", "constant_area"), ("area_min", "target"), ("pure_pursuit", "area_max")])
def test_triangle_arena_games_match_reference(pp, ep, rng):
    """A non-symmetric arena with a target inside it: the same capture times as the reference."""
    P, E = points_in(TRIANGLE, (3, 3), rng), points_in(TRIANGLE, (3, 1), rng)
    kw = dict(arena=TRIANGLE, t_max=20.0, pursuer_policy=pp, evader_policy=ep, target=(3.0, 1.0))
    res = simulate_games(P, E, record=True, **kw)
    assert_game_invariants(res)
    ref = np.array([reference_game(P[b], E[b], **kw) for b in range(3)])
    np.testing.assert_array_equal(res.capture_times, ref)


@pytest.mark.parametrize("pp,ep", PAIRS)
def test_agents_on_boundary_and_coincident_follow_the_reference(pp, ep):
    """Agents in corners, on edges and on top of each other. Controls equal the
    reference's along the game, except the documented coincident-agents choice
    (docs/engine.md, "Model choices"): of the two pursuers at (0, 0) only pursuer 0 is the
    evaders' neighbour at t = 0, so area_min sends pursuer 1 straight at its nearest
    evader, (10, 0), where the reference makes both neighbours."""
    p = np.array([[[0.0, 0.0], [0.0, 0.0], [10.0, 10.0], [0.0, 5.0]]])
    e = np.array([[[10.0, 0.0], [5.0, 10.0], [5.0, 10.0]]])
    res = simulate_games(p, e, pursuer_policy=pp, evader_policy=ep, record=True, t_max=30.0)
    assert_game_invariants(res)
    # coincident evaders move together and are caught together
    np.testing.assert_array_equal(res.evader_paths[:, 0, 1], res.evader_paths[:, 0, 2])
    assert res.capture_step[0, 1] == res.capture_step[0, 2]
    for f in range(0, res.steps[0], 25):  # states with an evader left
        alive = res.alive_at(f)[0]
        P, E = res.pursuer_paths[f, 0], res.evader_paths[f, 0]
        up, ue = step_velocities(P[None], E[None], alive[None], pursuer_policy=pp, evader_policy=ep)
        rp, re = reference_velocities(P, E, alive, pursuer_policy=pp, evader_policy=ep)
        if f == 0 and pp == "area_min":
            np.testing.assert_allclose(up[0, 1], [1.0, 0.0], atol=1e-12)
            up, rp = np.delete(up, 1, axis=1), np.delete(rp, 1, axis=0)
        np.testing.assert_allclose(up[0], rp, atol=1e-8)
        np.testing.assert_allclose(ue[0], re, atol=1e-8)


def test_hundred_vs_fifty_game_catches_everyone_consistently():
    rng = np.random.default_rng(1)
    P = np.stack([rng.uniform(3, 5, (1, 100)), rng.uniform(0, 10, (1, 100))], -1)
    E = np.stack([rng.uniform(7, 9, (1, 50)), rng.uniform(0, 10, (1, 50))], -1)
    res = simulate_games(P, E, record=True)
    assert (res.capture_step >= 0).all()
    assert_game_invariants(res)


BAD = [
    (dict(pursuers=np.zeros((2, 3))), "pursuers: positions must have shape"),
    (dict(evaders=np.full((1, 1, 2), np.nan)), "evaders: positions must be finite"),
    (dict(evaders=np.array([[[np.inf, 1.0]]])), "evaders: positions must be finite"),
    (dict(pursuers=np.array([[[11.0, 5.0]]])), "outside the arena"),
    (dict(pursuers=np.zeros((1, 0, 2))), "pursuers: the team is empty"),
    (dict(evaders=np.zeros((1, 0, 2))), "evaders: the team is empty"),
    (dict(evaders=np.ones((2, 1, 2))), "batch size"),
    (dict(pursuer_policy="chase"), "pursuer_policy: unknown policy 'chase'"),
    (dict(evader_policy="hide"), "evader_policy: unknown policy 'hide'"),
    (dict(dt=0.0), "dt: must be positive"),
    (dict(dt=-0.01), "dt: must be positive"),
    (dict(capture_radius=0), "capture_radius: must be positive"),
    (dict(t_max=-1), "t_max: must be positive"),
    (dict(t_max=float("nan")), "t_max: must be positive"),
    (dict(arena=[[0, 0], [10, 0], [5, 5], [10, 10], [0, 10]]), "arena: polygon must be strictly convex"),
    (dict(arena=[[0, 0], [5, 0], [10, 0]]), "arena: polygon is degenerate"),
    (dict(arena=[[0, 0], [10, 0]]), "arena: vertices must have shape"),
    (dict(arena=[[0, 0], [10, 0], [10, 0], [0, 10]]), "arena: polygon has repeated vertices"),
    (dict(target=(1.0,)), "target: must be a finite point"),
]


@pytest.mark.parametrize("bad,message", BAD)
def test_bad_input_one_line_error(bad, message):
    args = dict(pursuers=np.array([[[4.0, 5.0]]]), evaders=np.array([[[8.0, 5.0]]]))
    args.update(bad)
    with pytest.raises(InputError) as err:
        simulate_games(args.pop("pursuers"), args.pop("evaders"), **args)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_clockwise_arena_plays_the_same_games(rng):
    """An arena given clockwise is the same arena: the same games, number for number."""
    P, E = rng.random((4, 3, 2)) * 10, rng.random((4, 2, 2)) * 10
    ccw = simulate_games(P, E, t_max=20.0, record=True)
    cw = simulate_games(P, E, t_max=20.0, record=True, arena=[[0, 0], [0, 10], [10, 10], [10, 0]])
    np.testing.assert_array_equal(cw.capture_step, ccw.capture_step)
    np.testing.assert_array_equal(cw.pursuer_paths, ccw.pursuer_paths)
    np.testing.assert_array_equal(cw.evader_paths, ccw.evader_paths)
    Ph, Eh = points_in(HEXAGON, (3, 3), rng), points_in(HEXAGON, (3, 2), rng)
    a = simulate_games(Ph, Eh, t_max=20.0, arena=HEXAGON).capture_times
    b = simulate_games(Ph, Eh, t_max=20.0, arena=HEXAGON[::-1]).capture_times
    np.testing.assert_allclose(a, b, atol=0.05)  # same arena; vertex order may move round-off


def test_t_max_is_never_exceeded():
    """t_max = 0.015 with dt = 0.01 allows one step (round() would give two)."""
    p, e = np.array([[[5.0, 5.0]]]), np.array([[[5.0 + 0.25 + 0.015, 5.0]]])
    res = simulate_games(p, e, pursuer_policy="pure_pursuit", evader_policy="target", target=(9.9, 5.0), t_max=0.015)
    assert res.steps[0] == 1 and np.isnan(res.capture_times[0, 0])
    with pytest.raises(InputError, match="engine's limit"):
        simulate_games(p, e, dt=1e-300)


def test_agrees_with_the_numpy_engine_up_to_round_off_on_chaotic_games():
    """The compiled engine plays the numpy engine's (1.1.0) games: the same capture times,
    except in games so sensitive that a 1e-9 nudge of the start moves the outcome too,
    where the two implementations' different round-off (1e-15) may do the same."""
    import numpy_engine

    from workers import Case, sample_initial_positions

    for n_p, ep in [(3, "centroid"), (5, "centroid"), (1, "constant_area"), (4, "area_max")]:
        case = Case(n_p, 1, evader_policy=ep)
        P, E = sample_initial_positions(case, 7, 0, 30)
        ours = simulate_games(P, E, evader_policy=ep).capture_times[:, 0]
        theirs = numpy_engine.simulate_games(P, E, evader_policy=ep).capture_times[:, 0]
        differ = np.flatnonzero(ours != theirs)
        assert len(differ) <= 0.2 * len(ours), (n_p, ep, ours[differ], theirs[differ])
        nudges = np.random.default_rng(0).normal(size=(4,) + P.shape[1:]) * 1e-9
        for b in differ:
            nudged = [simulate_games(np.clip(P[b : b + 1] + d, 0, 10), E[b : b + 1],
                                     evader_policy=ep).capture_times[0, 0] for d in nudges]
            assert any(t != ours[b] for t in nudged), f"game {b} differs ({ours[b]} vs {theirs[b]}) but is not chaotic"


def test_controls_equal_the_numpy_engines_along_trajectories(rng):
    """At every recorded state of random games, the compiled controls equal the numpy engine's to 1e-9."""
    import numpy_engine

    for pp in PURSUERS:
        for ep in EVADERS:
            P, E = rng.random((2, 6, 2)) * 10, rng.random((2, 4, 2)) * 10
            res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=4.0, record=True)
            frames = np.arange(0, res.pursuer_paths.shape[0], 13)
            p, e = res.pursuer_paths[frames].reshape(-1, 6, 2), res.evader_paths[frames].reshape(-1, 4, 2)
            alive = np.concatenate([res.alive_at(f) for f in frames])
            keep = alive.any(axis=1)
            ours = step_velocities(p[keep], e[keep], alive[keep], pursuer_policy=pp, evader_policy=ep)
            theirs = numpy_engine.step_velocities(p[keep], e[keep], alive[keep], pursuer_policy=pp, evader_policy=ep)
            np.testing.assert_allclose(ours[0], theirs[0], atol=1e-9)
            np.testing.assert_allclose(ours[1], theirs[1], atol=1e-9)


@pytest.mark.parametrize("n_p,n_e", [(100, 50), (60, 200)])
def test_large_games_match_brute_force_cells_and_controls(n_p, n_e, rng):
    """Large teams take neighbour candidates from the grid: controls equal those of
    all-pairs clipping (the numpy engine) on clustered and spread-out states."""
    import numpy_engine

    clustered = np.stack([rng.uniform(3, 5, (2, n_p)), rng.uniform(4, 6, (2, n_p))], -1)
    spread = rng.random((2, n_p, 2)) * 10
    P = np.concatenate([clustered, spread])
    E = np.concatenate([np.stack([rng.uniform(7, 9, (2, n_e)), rng.uniform(0, 10, (2, n_e))], -1),
                        rng.random((2, n_e, 2)) * 10])
    alive = rng.random((4, n_e)) < 0.8
    for pp, ep in [("area_min", "centroid"), ("area_min", "constant_area")]:
        ours = step_velocities(P, E, alive, pursuer_policy=pp, evader_policy=ep)
        theirs = numpy_engine.step_velocities(P, E, alive, pursuer_policy=pp, evader_policy=ep)
        np.testing.assert_allclose(ours[0], theirs[0], atol=1e-9)
        np.testing.assert_allclose(ours[1], theirs[1], atol=1e-9)
