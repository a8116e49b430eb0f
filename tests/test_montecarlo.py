"""Monte Carlo sampling, per-game statistics and case summaries."""

import math

import numpy as np
import pytest

from workers import Case, InitialLaw, InputError, game_statistics, run_case, sample_initial_positions, summarize_case


def test_paper_law_boxes(rng):
    p, e = sample_initial_positions(Case(5, 3), seed=1, start=0, stop=200)
    assert p.shape == (200, 5, 2) and e.shape == (200, 3, 2)
    assert (p[..., 0] >= 3).all() and (p[..., 0] <= 5).all() and (p[..., 1] >= 0).all() and (p[..., 1] <= 10).all()
    assert (e[..., 0] >= 7).all() and (e[..., 0] <= 9).all()
    assert abs(p[..., 0].mean() - 4.0) < 0.05 and abs(e[..., 1].mean() - 5.0) < 0.2


def test_uniform_law_in_hexagon():
    hexagon = tuple((5 + 5 * math.cos(a), 5 + 5 * math.sin(a)) for a in np.arange(6) * math.pi / 3)
    case = Case(4, 2, arena=hexagon, law=InitialLaw(kind="uniform"))
    p, e = sample_initial_positions(case, 0, 0, 300)
    from workers import make_arena

    assert make_arena(hexagon).contains(p).all() and make_arena(hexagon).contains(e).all()


def test_games_depend_only_on_seed_and_index():
    case = Case(3, 2)
    whole = sample_initial_positions(case, 7, 0, 10)
    part = sample_initial_positions(case, 7, 4, 10)
    np.testing.assert_array_equal(whole[0][4:], part[0])
    np.testing.assert_array_equal(whole[1][4:], part[1])
    other = sample_initial_positions(case, 8, 0, 10)
    assert not np.array_equal(whole[0], other[0])


def test_run_case_same_seed_same_numbers_whatever_the_batching():
    case = Case(3, 2, t_max=20.0)
    a, sa = run_case(case, 12, seed=3, batch_size=12)
    b, sb = run_case(case, 12, seed=3, batch_size=5)
    np.testing.assert_array_equal(a.to_numpy(dtype=float), b.to_numpy(dtype=float))
    assert sa == sb


def test_game_statistics_by_hand():
    nan = math.nan
    ct = np.array([[1.0, 3.0, 6.0], [2.0, nan, 4.0], [nan, nan, nan]])
    df = game_statistics(ct, tau=5.0)
    np.testing.assert_allclose(df["first_capture"], [1.0, 2.0, nan])
    np.testing.assert_allclose(df["mean_capture"], [10 / 3, 3.0, nan])
    np.testing.assert_allclose(df["last_capture"], [6.0, nan, nan])
    np.testing.assert_allclose(df["frac_captured"], [1.0, 2 / 3, 0.0])
    np.testing.assert_allclose(df["frac_captured_tau"], [2 / 3, 2 / 3, 0.0])
    assert list(df["all_captured_tau"]) == [False, False, False]
    s = summarize_case(df)
    assert s["n_games"] == 3
    assert s["last_capture_n_censored"] == 2 and s["last_capture_mean"] == 6.0
    assert s["first_capture_mean"] == 1.5 and s["first_capture_std"] == pytest.approx(math.sqrt(0.5))
    half = 12.706204736174707 * math.sqrt(0.5) / math.sqrt(2)  # t_{0.975, 1}
    assert s["first_capture_ci95_high"] == pytest.approx(1.5 + half)
    assert s["p_all_captured_tau"] == 0.0
    assert s["frac_captured_mean"] == pytest.approx((1 + 2 / 3) / 3)


def test_case_key_changes_with_every_parameter():
    base = Case(3, 1)
    variants = [
        Case(4, 1), Case(3, 2), Case(3, 1, pursuer_policy="pure_pursuit"), Case(3, 1, evader_policy="target"),
        Case(3, 1, capture_radius=0.3), Case(3, 1, dt=0.02), Case(3, 1, t_max=30.0), Case(3, 1, tau=4.0),
        Case(3, 1, target=(0.0, 4.0)), Case(3, 1, arena=((0, 0), (10, 0), (10, 10), (0, 10))),
        Case(3, 1, law=InitialLaw(kind="uniform")), Case(3, 1, engine_version="0"),
    ]
    keys = {base.key()} | {v.key() for v in variants}
    assert len(keys) == len(variants) + 1
    assert Case(3, 1).key() == base.key()


@pytest.mark.parametrize(
    "case,message",
    [
        (Case(0, 1), "n_pursuers"),
        (Case(1, -2), "n_evaders"),
        (Case(1, 1, pursuer_policy="x"), "pursuer_policy"),
        (Case(1, 1, tau=0.0), "tau"),
        (Case(1, 1, law=InitialLaw(pursuer_box=(3, 12, 0, 10))), "law.pursuer_box"),
        (Case(1, 1, law=InitialLaw(kind="gauss")), "law.kind"),
    ],
)
def test_bad_case(case, message):
    with pytest.raises(InputError, match=message):
        case.validate()


def test_capture_at_exactly_tau_counts_as_within_tau():
    df = game_statistics(np.array([[35 * 0.01], [36 * 0.01]]), tau=0.35)
    assert list(df["frac_captured_tau"]) == [1.0, 0.0]


def test_case_numbers_have_one_spelling():
    assert Case(3, 1, t_max=60).key() == Case(3, 1, t_max=60.0).key()
    assert Case(3, 1, target=(0, 5)).key() == Case(3, 1).key()
    with pytest.raises(InputError, match="target: must be a finite point"):
        Case(3, 1, target=(float("nan"), 5.0)).validate()
