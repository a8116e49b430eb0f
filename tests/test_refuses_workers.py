"""Bad input never becomes a wrong result (issue 17, the workers/ part).

First the exact failures of the issue, each reproduced: a bool read as a number, NaN or
inf, a dict given for a Case, an exit point outside the arena, a near-degenerate arena,
a position printed rounded back inside the arena; a time step so coarse that captures
are missed gives one CoarseStepWarning. Then properties (hypothesis): whatever the
input, the outcome is a valid result or an InputError (a SwarmFarmError), never another
exception. Examples per property: Case(...).validate() 500, simulate_games 300, the
Monte Carlo entry points (run_games, sample_initial_positions, run_case) 200; every
game they play lasts at most 0.5 s of game time, so the file runs in about 15 s.
"""

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from helpers import raises_one_line
from hypothesis.extra import numpy as hnp

from workers import (
    Case,
    CoarseStepWarning,
    GameResults,
    InitialLaw,
    InputError,
    SwarmFarmError,
    make_arena,
    run_case,
    run_games,
    sample_initial_positions,
    simulate_case,
    simulate_games,
)
from workers.errors import exact, shown

P1 = np.array([[[4.0, 5.0]]])  # one pursuer, one game
E1 = np.array([[[8.0, 5.0]]])  # one evader
HEXAGON = [(5 + 5 * math.cos(a), 5 + 5 * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 7)[:-1]]


def refused(call, message: str) -> str:
    """The one-line message of the InputError that call() raises; asserts it contains `message`."""
    return raises_one_line(InputError, call, message)


# ---------------------------------------------------------------- 1. a bool is never a number
BOOL_CASES = [
    (dict(n_pursuers=True), "n_pursuers: must be a whole number >= 1, got True"),
    (dict(n_evaders=True), "n_evaders: must be a whole number >= 1, got True"),
    (dict(n_pursuers=np.bool_(True)), "n_pursuers: must be a whole number >= 1"),
    (dict(capture_radius=True), "capture_radius: must be positive and finite, got True (a bool is not a number)"),
    (dict(dt=True), "dt: must be positive and finite, got True"),
    (dict(t_max=True), "t_max: must be positive and finite, got True"),
    (dict(tau=np.True_), "tau: must be positive and finite"),
    (dict(pursuer_speed=True), "pursuer_speed: must be positive and finite, got True"),
    (dict(evader_speed=True), "evader_speed: must be positive and finite, got True"),
    (dict(target=(True, 5.0)), "target: must be a finite point (x, y), got (True, 5.0) (a bool is not a number)"),
    (dict(exit_point=(0.0, True)), "exit_point: must be a finite point (x, y), got (0.0, True)"),
    (dict(arena=((0, 0), (10, False), (10, 10), (0, 10))), "arena: vertices must be numbers of shape (k, 2) (a bool"),
    (dict(law=InitialLaw("boxes", (3, 5, False, 10), (7, 9, 0, 10))),
     "law.pursuer_box: must be (x_min, x_max, y_min, y_max), finite numbers, got (3.0, 5.0, False, 10.0)"),
    (dict(law=InitialLaw("uniform", (3, 5, 0, 10), (7, 9, True, 10))), "law.evader_box: must be"),
]


@pytest.mark.parametrize("fields,message", BOOL_CASES)
def test_case_refuses_a_bool_in_every_numeric_field(fields, message):
    """Case(target=(True, 5)) and the like were accepted (True read as 1); now validate names the field."""
    refused(Case(**{"n_pursuers": 2, "n_evaders": 1, **fields}).validate, message)


def test_no_game_is_built_from_a_case_with_a_bool():
    """run_games(Case(True, 1)) raised TypeError inside numpy; every path from a Case to a game
    now validates it first."""
    case = Case(True, 1, t_max=0.05)
    message = "n_pursuers: must be a whole number >= 1, got True"
    refused(lambda: run_games(case, 0, 0, 1), message)
    refused(lambda: sample_initial_positions(case, 0, 0, 1), message)
    refused(lambda: simulate_case(case, P1, E1), message)
    refused(lambda: run_case(case, 1, 0), message)
    refused(lambda: run_games(Case(2, 1, t_max=0.05, target=(True, 5.0)), 0, 0, 1), "target:")


@pytest.mark.parametrize("args,message", [
    (dict(capture_radius=True), "capture_radius: must be positive and finite, got True"),
    (dict(target=(True, 5.0)), "target: must be a finite point (x, y), got (True, 5.0) (a bool is not a number)"),
    (dict(exit_point=(0.0, True)), "exit_point: must be a finite point"),
    (dict(arena=[[0, 0], [10, 0], [10, True], [0, 10]]), "arena: vertices must be numbers"),
    (dict(pursuers=np.array([[[True, True]]])), "pursuers: positions must be numbers of shape (B, n, 2) (a bool"),
    (dict(evaders=[[[8.0, True]]]), "evaders: positions must be numbers of shape (B, n, 2) (a bool"),
    (dict(evaders=[[["8", "5"]]]), "evaders: positions must be numbers"),
    (dict(evaders=np.array([[[8 + 0j, 5]]])), "evaders: positions must be numbers"),
])
def test_simulate_games_refuses_a_bool_anywhere(args, message):
    """simulate_games(target=(True, 5)) and boolean positions were played as 1.0."""
    kw = dict(pursuers=P1, evaders=E1, t_max=0.05)
    kw.update(args)
    refused(lambda: simulate_games(kw.pop("pursuers"), kw.pop("evaders"), **kw), message)


def test_game_counts_and_seeds_refuse_bools():
    """run_case(case, n_games=True) played one game; run_games(case, 0, False, True) one too."""
    case = Case(2, 1, t_max=0.05, tau=0.05)
    refused(lambda: run_case(case, True, 0), "n_games: must be a whole number >= 1, got True")
    refused(lambda: run_case(case, 2, 0, batch_size=True), "batch_size: must be a whole number >= 1, got True")
    refused(lambda: run_case(case, 2, True), "seed: must be a whole number >= 0")
    refused(lambda: run_case(case, 2, 0, progress="yes"), "progress: must be a callable or None")
    refused(lambda: run_games(case, 0, False, 1), "start: must be a whole number >= 0, got False")
    refused(lambda: run_games(case, 0, 0, True), "stop: must be a whole number >= 0, got True")
    refused(lambda: run_games(case, (1, True), 0, 1), "seed:")
    refused(lambda: sample_initial_positions(case, 0, 2, 1), "stop: must be a whole number >= 2, got 1")
    refused(lambda: sample_initial_positions(case, 0, -1, 1), "start: must be a whole number >= 0, got -1")


def test_game_counts_too_large_to_hold_are_refused_before_any_array():
    """run_games(case, 0, 0, 10**400) raised numpy's ValueError ("Maximum allowed dimension
    exceeded") from np.empty (found by the property test below on CI); run_case(case, 10**400)
    would have played batches for ever."""
    case = Case(2, 1, t_max=0.05, tau=0.05)
    refused(lambda: run_games(case, 0, 0, 10**400), "stop: games 0..")
    refused(lambda: sample_initial_positions(case, 0, 5, 10**9),
            "GiB of starting positions in one batch, more than 4 GiB")
    refused(lambda: run_case(case, 10**400, 0), "n_games: must be at most 1,000,000,000")
    refused(lambda: run_case(case, 10**5000, 0), "got an integer of about 5,001 digits")  # past repr's limit
    refused(lambda: run_games(case, 0, 0, 10**5000), "need about 1e4992 GiB")
    refused(lambda: run_case(case, 10**9 + 1, 0, batch_size=10**400), "n_games: must be at most")
    assert run_case(case, 3, 0, batch_size=10**400)[0].shape[0] == 3  # a batch larger than the games is the games


# ---------------------------------------------------------------- 2. finite numbers only
@pytest.mark.parametrize("name", ["capture_radius", "dt", "t_max", "tau", "pursuer_speed", "evader_speed"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, np.float64("nan"), 10**400, np.complex128(1)])
def test_case_numbers_must_be_finite(name, bad):
    """NaN, inf, an int beyond float's range (was OverflowError) and a complex (was read as
    its real part) are refused, naming the field."""
    refused(Case(2, 1, **{name: bad}).validate, f"{name}: must be positive and finite")


@pytest.mark.parametrize("fields,message", [
    (dict(target=(math.inf, 5.0)), "target: must be a finite point"),
    (dict(exit_point=(0.0, math.nan)), "exit_point: must be a finite point"),
    (dict(arena=[[0, 0], [10, 0], [10, math.inf], [0, 10]]), "arena: vertices must be finite"),
    (dict(arena=[[0, 0], [1e200, 0], [1e200, 1e200], [0, 1e200]]), "arena: vertices are too large"),
    (dict(law=InitialLaw("boxes", (3, 5, math.nan, 10), (7, 9, 0, 10))), "law.pursuer_box: must be"),
    (dict(law=InitialLaw("boxes", (3, 5, 0, 10), (7, 9, 0, math.inf))), "law.evader_box: must be"),
    (dict(law=InitialLaw("boxes", None, (7, 9, 0, 10))), "law.pursuer_box: must be"),  # was TypeError
    (dict(law={"kind": "uniform"}), "law: expected a workers.InitialLaw, got dict"),  # was AttributeError
    (dict(arena=[[0, 0], 3]), "arena: vertices must be numbers"),  # Case() raised TypeError
    (dict(n_pursuers=np.zeros((3, 3))), "n_pursuers: must be a whole number >= 1, got array([[0., 0., 0.], [0."),
    (dict(n_evaders=10**400), "n_evaders: 1000000000"),  # sample_initial_positions raised ValueError
    (dict(n_pursuers=1_000_001), "n_pursuers: 1000001 agents is more than the engine's limit of 1000000"),
])
def test_case_points_arena_and_law_must_be_finite_numbers(fields, message):
    """Nested numbers are checked too, and odd values give the field's one-line message."""
    refused(Case(**{"n_pursuers": 2, "n_evaders": 1, **fields}).validate, message)


@pytest.mark.parametrize("args,message", [
    (dict(t_max=math.inf), "t_max: must be positive and finite, got inf"),
    (dict(dt=math.nan), "dt: must be positive and finite, got nan"),
    (dict(capture_radius=-math.inf), "capture_radius: must be positive and finite"),
    (dict(pursuer_speed=math.inf), "pursuer_speed: must be positive and finite"),
    (dict(evader_speed=math.nan), "evader_speed: must be positive and finite"),
    (dict(target=(math.nan, 5.0)), "target: must be a finite point"),
    (dict(exit_point=(0.0, math.inf)), "exit_point: must be a finite point"),
    (dict(t_max=1e300, dt=1e-300), "t_max/dt: inf steps is more than the engine's limit"),  # was OverflowError
    (dict(evaders=[[[8.0, 10**400]]]), "evaders: positions must be numbers"),  # was OverflowError
])
def test_simulate_games_numbers_must_be_finite(args, message):
    """Each argument's NaN or inf is an InputError naming it; so is t_max/dt overflowing."""
    kw = dict(pursuers=P1, evaders=E1, t_max=0.05)
    kw.update(args)
    refused(lambda: simulate_games(kw.pop("pursuers"), kw.pop("evaders"), **kw), message)


# ---------------------------------------------------------------- 3. a dict is not a Case
@pytest.mark.parametrize("call", [
    lambda c: run_case(c, 1, 0), lambda c: run_games(c, 0, 0, 1), lambda c: simulate_case(c, P1, E1),
    lambda c: sample_initial_positions(c, 0, 0, 1),
], ids=["run_case", "run_games", "simulate_case", "sample_initial_positions"])
def test_a_dict_is_not_a_case(call):
    """run_case({...}) raised AttributeError: 'dict' object has no attribute 'validate'."""
    text = refused(lambda: call({"n_pursuers": 2, "n_evaders": 1}), "case: expected a workers.Case, got dict")
    assert text == ("case: expected a workers.Case, got dict; build one with Case(n_p, n_e, ...) "
                    "or farm.core.config.case_from(mapping)")


# ---------------------------------------------------------------- 4. physical sanity
def test_an_exit_point_outside_the_arena_is_refused():
    """An exit no evader can reach was accepted (its games never escape); on the boundary it is fine."""
    refused(Case(2, 1, exit_point=(-5, 5)).validate, "exit_point: (-5, 5) is outside the arena")
    refused(Case(2, 1, exit_point=(11.0, 5.0), arena=HEXAGON).validate, "exit_point: (11, 5) is outside")
    refused(lambda: simulate_games(P1, E1, t_max=0.05, exit_point=(-5, 5)),
            "exit_point: (-5, 5) is outside the arena")
    refused(lambda: simulate_games(P1, E1, t_max=0.05, exit_point=(10.0000001, 5.0)),
            "exit_point: (10.0000001, 5) is outside the arena")
    assert Case(2, 1, exit_point=(0.0, 5.0)).validate().exit_point == (0.0, 5.0)
    assert simulate_games(P1, E1, t_max=0.05, exit_point=(0.0, 5.0)).exit_point == (0.0, 5.0)


def _warnings_of(call) -> list:
    """The CoarseStepWarnings call() emits (every one recorded) and its result."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = call()
    return [w for w in caught if issubclass(w.category, CoarseStepWarning)], result


def test_a_coarse_step_warns_once_naming_the_ratio():
    """At dt 5 an agent moves 20 capture radii a step: a 5v1 game's capture comes late or never,
    with no sign that the number is the step's; now one CoarseStepWarning says so."""
    case = Case(5, 1, dt=5.0)
    P, E = sample_initial_positions(case, 0, 0, 2)
    caught, res = _warnings_of(lambda: simulate_case(case, P, E))
    assert len(caught) == 1 and res.n_games == 2
    assert str(caught[0].message) == ("dt: agents move up to 20 capture radii per step (speed 1 x dt 5 / "
                                      "capture_radius 0.25); captures may come late or be missed")
    assert caught[0].filename.endswith("montecarlo.py")  # attributed to simulate_games' caller
    caught, _ = _warnings_of(lambda: simulate_games(P1, E1, dt=0.2, t_max=0.4, evader_speed=2.0))
    assert [str(w.message) for w in caught] == [
        "dt: agents move up to 1.6 capture radii per step (speed 2 x dt 0.2 / capture_radius 0.25); "
        "captures may come late or be missed"]
    assert caught[0].filename == __file__


def test_the_paper_and_allocation_settings_do_not_warn():
    """The paper's defaults (dt 0.01, r_c 0.25, speeds 1), the allocation env's v2 games and a
    step of exactly one capture radius give no CoarseStepWarning."""
    from farm.alloc.game.config import AllocConfig

    for case in (Case(2, 1, t_max=0.05), replace(AllocConfig().game(), t_max=0.05), Case(2, 1, dt=0.25, t_max=0.5)):
        caught, _ = _warnings_of(lambda case=case: run_games(case, 0, 0, 1))
        assert caught == [], case


def test_a_near_degenerate_arena_is_refused():
    """Three almost collinear vertices made an arena of area 1e-8 (1e-9 thin): refused, at every scale."""
    text = refused(lambda: make_arena([(0, 0), (10, 1e-9), (20, 0)]), "arena: polygon is degenerate (area 1e-08")
    assert "1e-09 x its bounding box's diagonal squared, 400" in text
    for scale in (1e-6, 1e6):
        refused(lambda s=scale: make_arena([(0, 0), (10 * s, 1e-9 * s), (20 * s, 0)]),
                "arena: polygon is degenerate")
    refused(Case(2, 1, arena=((0, 0), (10, 1e-9), (20, 0))).validate, "arena: polygon is degenerate")
    assert make_arena([(0, 0), (10, 0), (10, 1e-3), (0, 1e-3)]).area == pytest.approx(1e-2)  # thin but fine


# ---------------------------------------------------------------- 5. exact coordinates in messages
def test_a_position_just_outside_is_printed_exactly():
    """x = 10.0000001 printed as (10, 5): a point inside the arena. Now the message shows why."""
    text = refused(lambda: simulate_games(np.array([[[10.0000001, 5.0]]]), E1, t_max=0.05),
                   "pursuers: agent 0 of game 0 at (10.0000001, 5) is outside the arena")
    x = float(text.split("at (")[1].split(",")[0])
    assert not make_arena(None).contains(np.array([x, 5.0]))
    assert exact(18.0) == "18" and exact(10.0000001) == "10.0000001" and exact(1 / 3) == "0.3333333333333333"


# ---------------------------------------------------------------- 6. properties
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])
JUNK = st.one_of(
    st.none(), st.booleans(), st.text(max_size=4), st.integers(-3, 12),
    st.floats(allow_nan=True, allow_infinity=True), st.just(10**400), st.just(1 + 2j),
)
JUNK_TREE = st.recursive(JUNK, lambda inner: st.one_of(st.lists(inner, max_size=5), st.tuples(inner, inner)),
                         max_leaves=10)
POINTS = st.tuples(st.floats(-1, 11), st.floats(-1, 11))
BOX = st.tuples(st.floats(-1, 11), st.floats(-1, 11), st.floats(-1, 11), st.floats(-1, 11))
ARENAS = st.one_of(st.none(), st.just(HEXAGON), st.just([(0, 0), (10, 1e-9), (20, 0)]),
                   st.lists(POINTS, min_size=0, max_size=6), JUNK_TREE)
LAWS = st.one_of(st.builds(InitialLaw, st.sampled_from(["boxes", "uniform"]), BOX, BOX),
                 st.builds(InitialLaw, JUNK, JUNK_TREE, JUNK_TREE), st.just(InitialLaw()), JUNK)


def mostly(plausible):
    """A plausible value two times in three, else anything."""
    return st.one_of(plausible, plausible, JUNK_TREE)


def some_junk(plausible: dict, bad: dict):
    """Dicts of a plausible value for every name, then 0 to 2 names' values replaced by
    anything (JUNK_TREE, or the name's own bad values in `bad`)."""
    @st.composite
    def build(draw):
        out = {name: draw(values) for name, values in plausible.items()}
        for name in draw(st.lists(st.sampled_from(sorted(plausible)), max_size=2, unique=True)):
            out[name] = draw(st.one_of(JUNK_TREE, bad.get(name, JUNK_TREE)))
        return out

    return build()


NOT_POSITIVE = st.one_of(NON_FINITE, st.floats(max_value=0.0), st.just(np.float64("nan")))
SETTINGS = {  # plausible values of the settings Case and simulate_games share
    "pursuer_policy": st.sampled_from(["area_min", "pure_pursuit"]),
    "evader_policy": st.sampled_from(["centroid", "target", "area_max", "constant_area"]),
    "capture_radius": st.floats(0.01, 3.0),
    "dt": st.floats(1e-3, 0.05),
    "t_max": st.floats(5e-3, 0.5),
    "target": POINTS,
    "arena": st.one_of(st.none(), st.none(), st.just(HEXAGON)),
    "exit_point": st.one_of(st.none(), st.tuples(st.floats(0, 10), st.floats(0, 10))),
    "pursuer_speed": st.floats(0.1, 3.0),
    "evader_speed": st.floats(0.1, 3.0),
}
BAD_SETTINGS = {
    "pursuer_policy": st.text(max_size=6), "evader_policy": st.text(max_size=6), "capture_radius": NOT_POSITIVE,
    "dt": st.one_of(NOT_POSITIVE, st.just(1e-300)), "t_max": NOT_POSITIVE, "target": BOX, "arena": ARENAS,
    "exit_point": st.one_of(POINTS, st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))),
    "pursuer_speed": NOT_POSITIVE, "evader_speed": NOT_POSITIVE,
}
CASE_FIELDS = some_junk(
    {"n_pursuers": st.integers(1, 5), "n_evaders": st.integers(1, 5), **SETTINGS, "tau": st.floats(0.1, 10.0),
     "law": st.sampled_from([InitialLaw(), InitialLaw("uniform")])},
    {"n_pursuers": st.integers(-3, 0), "n_evaders": st.integers(-3, 0), **BAD_SETTINGS, "tau": NOT_POSITIVE,
     "law": LAWS})


def _case_is_sane(case: Case) -> None:
    """Asserts what validate promises of a Case it accepts."""
    for name in ("n_pursuers", "n_evaders"):
        v = getattr(case, name)
        assert isinstance(v, int) and not isinstance(v, bool) and v >= 1
    for name in ("capture_radius", "dt", "t_max", "tau", "pursuer_speed", "evader_speed"):
        v = getattr(case, name)
        assert type(v) is float and math.isfinite(v) and v > 0, (name, v)
    arena = make_arena(case.arena)
    for p in (case.target, case.exit_point):
        assert p is None or (len(p) == 2 and all(type(x) is float and math.isfinite(x) for x in p))
    if case.exit_point is not None:
        assert arena.contains(np.array(case.exit_point))


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(CASE_FIELDS)
def test_property_case_is_valid_or_refused(fields):
    """Case(**anything).validate() returns a sane Case or raises InputError; nothing else."""
    try:
        case = Case(**fields).validate()
    except InputError as e:
        assert "\n" not in str(e) and ": " in str(e)
        return
    _case_is_sane(case)
    P, E = sample_initial_positions(case, 0, 0, 1)
    assert P.shape == (1, case.n_pursuers, 2) and E.shape == (1, case.n_evaders, 2)
    arena = make_arena(case.arena)
    assert arena.contains(P).all() and arena.contains(E).all()


ODD_POSITIONS = st.one_of(
    hnp.arrays(st.sampled_from([np.float64, np.float32, np.int64, np.bool_, np.complex128]),
               hnp.array_shapes(min_dims=0, max_dims=4, max_side=3), elements=None),
    hnp.arrays(np.float64, st.tuples(st.integers(0, 2), st.integers(0, 2), st.just(2)),
               elements=st.one_of(st.floats(-1, 11), NON_FINITE)),
    JUNK_TREE,
)


@st.composite
def games(draw, team_max: int = 3):
    """(pursuers, evaders): mostly plausible positions (B, n, 2) of B <= 2 games in [2, 8]^2
    (inside both the square and HEXAGON), at times either team's arrays of any shape, dtype
    and values."""
    b = draw(st.integers(0, 2))
    teams = []
    for _ in range(2):
        n = draw(st.integers(1, team_max))
        plausible = hnp.arrays(np.float64, (b, n, 2), elements=st.floats(2, 8))
        teams.append(draw(ODD_POSITIONS if draw(st.integers(0, 7)) == 7 else plausible))
    return tuple(teams)


SIM_ARGS = some_junk({**SETTINGS, "record": st.booleans()}, BAD_SETTINGS)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(games(), SIM_ARGS)
def test_property_simulate_games_plays_or_refuses(teams, args):
    """simulate_games(anything) returns GameResults of the documented shapes (and warns iff
    the step is coarse) or raises InputError; nothing else."""
    pursuers, evaders = teams
    try:
        caught, res = _warnings_of(lambda: simulate_games(pursuers, evaders, **args))
    except InputError as e:
        assert "\n" not in str(e) and ": " in str(e)
        return
    B, n_p, n_e = np.shape(pursuers)[0], np.shape(pursuers)[1], np.shape(evaders)[1]
    assert isinstance(res, GameResults) and res.n_games == B
    for a, dtype in ((res.capture_times, np.float64), (res.escape_times, np.float64),
                     (res.capture_step, np.int64), (res.escape_step, np.int64)):
        assert a.shape == (B, n_e) and a.dtype == dtype
    assert res.steps.shape == (B,) and (res.steps <= res.t_max / res.dt + 1e-6).all()
    captured = res.capture_step >= 0
    np.testing.assert_array_equal(res.capture_times[captured], res.capture_step[captured] * res.dt)
    assert np.isnan(res.capture_times[~captured]).all()
    assert not (captured & (res.escape_step >= 0)).any()
    if args["record"]:
        T = int(res.steps.max(initial=0)) + 1
        assert res.pursuer_paths.shape == (T, B, n_p, 2) and res.evader_paths.shape == (T, B, n_e, 2)
        assert res.arena.contains(res.pursuer_paths).all() and res.arena.contains(res.evader_paths).all()
    coarse = max(res.pursuer_speed, res.evader_speed) * res.dt / res.capture_radius > 1.0
    assert len(caught) == int(coarse)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.just(Case(2, 1, t_max=0.05, tau=0.05)),
                 st.just(Case(1, 2, t_max=0.05, tau=0.05, law=InitialLaw("uniform"))),
                 st.just({"n_pursuers": 2, "n_evaders": 1}), st.builds(Case, JUNK, JUNK), JUNK),
       mostly(st.one_of(st.integers(0, 2**64), st.tuples(st.integers(0, 9), st.integers(0, 9)))),
       mostly(st.integers(-1, 3)), mostly(st.integers(-1, 4)), st.sampled_from(["run_games", "sample", "run_case"]))
@example(Case(2, 1, t_max=0.05, tau=0.05), 0, 0, 10**400, "run_games")  # CI, stop 44's successor: numpy's ValueError
def test_property_montecarlo_plays_or_refuses(case, seed, start, stop, entry):
    """run_games, sample_initial_positions and run_case (stop as n_games, start as batch_size)
    with any case, seed, start and stop: a result for the games asked, or InputError."""
    try:
        if entry == "run_games":
            out = run_games(case, seed, start, stop)
            assert out.n_games == stop - start
        elif entry == "sample":
            P, E = sample_initial_positions(case, seed, start, stop)
            assert P.shape == (stop - start, case.n_pursuers, 2) and E.shape == (stop - start, case.n_evaders, 2)
        else:
            per_game, summary = run_case(case, stop, seed, batch_size=start)
            assert len(per_game) == stop
    except SwarmFarmError as e:
        assert isinstance(e, InputError) and "\n" not in str(e)


def test_shown_keeps_messages_on_one_line():
    """An array's repr spans lines and a huge value's is long: shown() makes one short line."""
    assert shown(np.zeros((3, 3))) == "array([[0., 0., 0.], [0., 0., 0.], [0., 0., 0.]])"
    assert len(shown(10**400)) == 80 and shown(10**400).endswith("...")
    assert shown(-10**5000) == "an integer of about 5,001 digits"  # repr raises past 4,300 digits
    assert shown([1, 10**5000]) == "a list holding an integer too long to print"
