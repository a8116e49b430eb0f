"""Monte Carlo sampling, per-game statistics and case summaries."""

import math

import numpy as np
import pytest

from workers import CaptureStats, Case, InitialLaw, InputError, game_statistics, run_case, sample_initial_positions


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
    np.testing.assert_equal(sa.flat(), sb.flat())


def _flat(per_game) -> dict:
    return CaptureStats.from_games(per_game).flat()


def test_capture_stats_flat_round_trip_and_the_stores_former_rows():
    """flat() and from_flat() are inverse; a store row written before CaptureStats (with
    expected_frac_captured_tau, estimate and key beside the statistics) reads the same."""
    _, stats = run_case(Case(2, 2, t_max=10.0), 5, seed=1)
    row = stats.flat()
    np.testing.assert_equal(CaptureStats.from_flat(row).flat(), row)
    former = {**row, "expected_frac_captured_tau": row["frac_captured_tau_mean"], "estimate": False, "key": "ab"}
    np.testing.assert_equal(CaptureStats.from_flat(former).flat(), row)
    assert CaptureStats.from_flat(former).frac_captured_tau == stats.frac_captured_tau
    with pytest.raises(InputError, match="unknown fields bogus"):
        CaptureStats.from_flat({**row, "bogus": 1})


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
    s = _flat(df)
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
        Case(3, 1, exit_point=(0.0, 5.0)), Case(3, 1, exit_point=(0.0, 4.0)), Case(3, 1, pursuer_speed=2.0),
        Case(3, 1, evader_speed=0.5),
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
        (Case(1, 1, exit_point=(math.nan, 5.0)), "exit_point: must be a finite point (x, y), got (nan, 5.0)"),
        (Case(1, 1, exit_point=(1.0, 2.0, 3.0)), "exit_point: must be a finite point"),
        (Case(1, 1, exit_point="top"), "exit_point: must be a finite point"),
        (Case(1, 1, pursuer_speed=0), "pursuer_speed: must be positive and finite, got 0.0"),
        (Case(1, 1, pursuer_speed=-2.0), "pursuer_speed: must be positive and finite"),
        (Case(1, 1, evader_speed=math.inf), "evader_speed: must be positive and finite, got inf"),
        (Case(1, 1, evader_speed=True), "evader_speed: must be positive and finite"),
        (Case(1, 1, evader_speed="fast"), "evader_speed: must be positive and finite"),
    ],
)
def test_bad_case(case, message):
    with pytest.raises(InputError) as err:
        case.validate()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_capture_at_exactly_tau_counts_as_within_tau():
    df = game_statistics(np.array([[35 * 0.01], [36 * 0.01]]), tau=0.35)
    assert list(df["frac_captured_tau"]) == [1.0, 0.0]


def test_case_numbers_have_one_spelling():
    assert Case(3, 1, t_max=60).key() == Case(3, 1, t_max=60.0).key()
    assert Case(3, 1, target=(0, 5)).key() == Case(3, 1).key()
    with pytest.raises(InputError, match="target: must be a finite point"):
        Case(3, 1, target=(float("nan"), 5.0)).validate()


# ---------------------------------------------------------------- escapes and team speeds


def test_new_fields_defaults_and_key_fields():
    d = Case(3, 1).to_dict()
    before = {"n_pursuers", "n_evaders", "pursuer_policy", "evader_policy", "capture_radius", "dt", "t_max", "tau",
              "target", "arena", "law", "engine_version"}
    assert set(d) == before | {"exit_point", "pursuer_speed", "evader_speed"}
    assert d["exit_point"] is None and d["pursuer_speed"] == 1.0 and d["evader_speed"] == 1.0
    assert Case(3, 1).validate().exit_point is None


def test_new_fields_have_one_spelling():
    assert Case(3, 1, exit_point=[0, 5]).key() == Case(3, 1, exit_point=(0.0, 5.0)).key()
    assert Case(3, 1, exit_point=np.array([0, 5])).exit_point == (0.0, 5.0)
    assert Case(3, 1, pursuer_speed=2).key() == Case(3, 1, pursuer_speed=2.0).key()
    assert Case(3, 1, evader_speed=np.float32(0.5)).evader_speed == 0.5
    assert type(Case(3, 1, evader_speed=np.int64(1)).evader_speed) is float
    assert Case(3, 1, pursuer_speed=1, evader_speed=1.0).key() == Case(3, 1).key()


def test_game_statistics_escape_columns_by_hand():
    nan = math.nan
    # game 0: evader 0 captured at 1, evader 1 escaped at 2, evader 2 escaped at 6 (after tau = 5)
    # game 1: evader 0 escaped at exactly tau (0.35 s window below), the rest neither
    # game 2: nobody captured or escaped
    ct = np.array([[1.0, nan, nan], [nan, nan, nan], [nan, nan, nan]])
    et = np.array([[nan, 2.0, 6.0], [5.0, nan, nan], [nan, nan, nan]])
    df = game_statistics(ct, tau=5.0, escape_times=et)
    np.testing.assert_allclose(df["frac_escaped"], [2 / 3, 1 / 3, 0.0])
    np.testing.assert_allclose(df["frac_escaped_tau"], [1 / 3, 1 / 3, 0.0])
    np.testing.assert_allclose(df["first_escape"], [2.0, 5.0, nan])
    np.testing.assert_allclose(df["mean_escape"], [4.0, 5.0, nan])
    np.testing.assert_allclose(df["frac_captured"], [1 / 3, 0.0, 0.0])
    for col in ("frac_escaped", "frac_escaped_tau", "first_escape", "mean_escape"):
        assert df[col].dtype == np.float64
    # the capture columns do not depend on the escapes
    plain = game_statistics(ct, tau=5.0)
    capture_cols = ["game", "first_capture", "mean_capture", "last_capture", "frac_captured", "frac_captured_tau",
                    "all_captured_tau"]
    assert df[capture_cols].equals(plain[capture_cols])
    # an escape at exactly tau counts, like a capture
    at_tau = game_statistics(np.full((2, 1), nan), tau=0.35, escape_times=np.array([[35 * 0.01], [36 * 0.01]]))
    assert list(at_tau["frac_escaped_tau"]) == [1.0, 0.0]


def test_game_statistics_without_escapes_has_the_columns():
    df = game_statistics(np.array([[1.0, 2.0], [math.nan, 3.0]]), tau=5.0)
    assert list(df["frac_escaped"]) == [0.0, 0.0] and list(df["frac_escaped_tau"]) == [0.0, 0.0]
    assert df["first_escape"].isna().all() and df["mean_escape"].isna().all()
    with pytest.raises(InputError, match="escape_times: must have the shape"):
        game_statistics(np.zeros((2, 2)), tau=5.0, escape_times=np.zeros((2, 3)))


def test_capture_stats_escape_statistics():
    nan = math.nan
    ct = np.array([[1.0, nan], [nan, nan], [2.0, 3.0], [nan, nan]])
    et = np.array([[nan, 2.0], [4.0, 8.0], [nan, nan], [nan, nan]])
    s = _flat(game_statistics(ct, tau=5.0, escape_times=et))
    assert s["frac_escaped_mean"] == pytest.approx((0.5 + 1.0 + 0 + 0) / 4)
    assert s["frac_escaped_tau_mean"] == pytest.approx((0.5 + 0.5 + 0 + 0) / 4)
    # first_escape per game: 2, 4, nan, nan; mean_escape: 2, 6, nan, nan
    assert s["first_escape_n_censored"] == 2 and s["mean_escape_n_censored"] == 2
    assert s["first_escape_mean"] == 3.0 and s["first_escape_std"] == pytest.approx(math.sqrt(2))
    assert s["first_escape_min"] == 2.0 and s["first_escape_max"] == 4.0 and s["first_escape_q50"] == 3.0
    half = 12.706204736174707 * math.sqrt(2) / math.sqrt(2)  # t_{0.975, 1}
    assert s["first_escape_ci95_low"] == pytest.approx(3.0 - half)
    assert s["mean_escape_mean"] == 4.0 and s["mean_escape_max"] == 6.0
    # the capture numbers are the same as without escapes
    plain = _flat(game_statistics(ct, tau=5.0))
    same = {k: v for k, v in plain.items() if "escape" not in k}
    assert all(s[k] == v or (math.isnan(s[k]) and math.isnan(v)) for k, v in same.items())
    # nobody escaped: NaN time statistics, everything censored
    assert plain["frac_escaped_mean"] == 0.0 and plain["first_escape_n_censored"] == 4
    assert math.isnan(plain["first_escape_mean"]) and math.isnan(plain["mean_escape_q95"])


def test_run_case_records_escapes():
    """Evaders heading for the exit at (0, 5) against one slow pure pursuer: some escape,
    none is both captured and escaped, and the numbers are the engine's."""
    from workers import run_games

    case = Case(1, 2, pursuer_policy="pure_pursuit", evader_policy="target", exit_point=(0.0, 5.0), t_max=15.0,
                tau=10.0, pursuer_speed=0.5)
    per_game, s = run_case(case, 6, seed=0)
    s = s.flat()
    res = run_games(case, 0, 0, 6)
    assert not (np.isfinite(res.capture_times) & np.isfinite(res.escape_times)).any()
    np.testing.assert_array_equal(per_game[["frac_escaped", "first_escape", "mean_escape"]].to_numpy(),
                                  game_statistics(res.capture_times, case.tau, escape_times=res.escape_times)
                                  [["frac_escaped", "first_escape", "mean_escape"]].to_numpy())
    assert s["frac_escaped_mean"] > 0 and s["frac_escaped_mean"] + s["frac_captured_mean"] <= 1.0
    assert s["first_escape_n_censored"] < 6
    no_exit = run_games(Case(1, 2, pursuer_policy="pure_pursuit", evader_policy="target", t_max=15.0, tau=10.0,
                             pursuer_speed=0.5), 0, 0, 6)
    assert np.isnan(no_exit.escape_times).all()


def test_faster_pursuers_capture_sooner():
    slow, fast = (run_case(Case(3, 1, pursuer_policy="pure_pursuit", evader_policy="target", pursuer_speed=v), 8,
                           seed=0)[1] for v in (1.0, 2.0))
    assert fast.last_capture.mean < slow.last_capture.mean
    np.testing.assert_equal(slow.flat(), run_case(Case(3, 1, pursuer_policy="pure_pursuit", evader_policy="target"),
                                                  8, seed=0)[1].flat())
