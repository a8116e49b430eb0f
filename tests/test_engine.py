"""The batched engine against the slow reference (workers.reference), analytic
cases and SPEC.md invariants."""

import numpy as np
import pytest

from conftest import HEXAGON, points_in
from workers import InputError, simulate_games
from workers.engine import step_velocities
from workers.geometry import voronoi_cells
from workers.reference import reference_game, reference_velocities

PURSUERS = ["area_min", "pure_pursuit"]
EVADERS = ["constant_area", "centroid", "target", "area_max"]
SIZES = [(1, 1), (3, 1), (5, 1), (4, 3)]


@pytest.mark.parametrize("pp", PURSUERS)
@pytest.mark.parametrize("ep", EVADERS)
def test_velocities_match_reference_along_trajectories(pp, ep, rng):
    """Every recorded state of random games: the engine's controls equal the reference's."""
    for n_p, n_e in SIZES:
        P, E = rng.random((3, n_p, 2)) * 10, rng.random((3, n_e, 2)) * 10
        res = simulate_games(P, E, pursuer_policy=pp, evader_policy=ep, t_max=8.0, record=True)
        for frame in range(0, res.pursuer_paths.shape[0], 7):
            alive = res.alive_at(frame)
            for b in np.flatnonzero(alive.any(axis=1) & (res.steps >= frame)):
                p, e = res.pursuer_paths[frame, b], res.evader_paths[frame, b]
                up, ue = step_velocities(p[None], e[None], alive[b][None], pursuer_policy=pp, evader_policy=ep)
                rp, re = reference_velocities(p, e, alive[b], pursuer_policy=pp, evader_policy=ep)
                np.testing.assert_allclose(up[0], rp, atol=1e-8)
                np.testing.assert_allclose(ue[0], re, atol=1e-8)


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


def test_captured_evader_leaves_the_game():
    """Evader 0 is caught at once; evader 1 must then be chased by everyone."""
    p = np.array([[[2.0, 5.0], [2.0, 6.0]]])
    e = np.array([[[2.1, 5.0], [8.0, 5.0]]])
    res = simulate_games(p, e, pursuer_policy="pure_pursuit", evader_policy="centroid", record=True)
    assert res.capture_times[0, 0] == 0.0
    np.testing.assert_array_equal(res.evader_paths[:, 0, 0], np.broadcast_to([2.1, 5.0], (len(res.evader_paths), 2)))
    assert np.isfinite(res.capture_times[0, 1])


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
    """SPEC.md: under area_min the evader's cell is non-increasing for any evader
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


def test_non_square_arena_game(rng):
    P, E = points_in(HEXAGON, (4, 3), rng), points_in(HEXAGON, (4, 2), rng)
    res = simulate_games(P, E, arena=HEXAGON, t_max=20.0, record=True)
    from workers import make_arena

    assert make_arena(HEXAGON).contains(res.pursuer_paths).all()
    assert make_arena(HEXAGON).contains(res.evader_paths).all()
    ref = np.array([reference_game(P[b], E[b], arena=HEXAGON, t_max=20.0) for b in range(4)])
    assert np.array_equal(np.isnan(res.capture_times), np.isnan(ref))


def test_agents_on_boundary_and_coincident_run_without_nan():
    p = np.array([[[0.0, 0.0], [0.0, 0.0], [10.0, 10.0], [0.0, 5.0]]])
    e = np.array([[[10.0, 0.0], [5.0, 10.0], [5.0, 10.0]]])
    for ep in EVADERS:
        res = simulate_games(p, e, evader_policy=ep, record=True, t_max=30.0)
        assert np.all(np.isfinite(res.pursuer_paths)) and np.all(np.isfinite(res.evader_paths))


def test_hundred_vs_fifty_game_finishes():
    rng = np.random.default_rng(1)
    P = np.stack([rng.uniform(3, 5, (1, 100)), rng.uniform(0, 10, (1, 100))], -1)
    E = np.stack([rng.uniform(7, 9, (1, 50)), rng.uniform(0, 10, (1, 50))], -1)
    res = simulate_games(P, E)
    assert np.isfinite(res.capture_times).all()


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


def test_clockwise_arena_is_accepted():
    res = simulate_games(np.array([[[4.0, 5.0]]]), np.array([[[8.0, 5.0]]]), arena=[[0, 0], [0, 10], [10, 10], [10, 0]])
    assert np.isfinite(res.capture_times).all()


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
            nudged = [simulate_games(np.clip(P[b : b + 1] + d, 0, 10), E[b : b + 1], evader_policy=ep).capture_times[0, 0]
                      for d in nudges]
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
