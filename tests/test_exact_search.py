"""The intruders' exact best response (farm.alloc.intruders.exact_search, farm.studies.exploit): the search
against a plain recursive enumeration written here, a replay of its routings through play() to the
bit, its size refusal, never worse than a heuristic of the registry, and on Ray the same table as
in process whatever the workers. Small real games (4 a case) in a store under tmp_path."""

import itertools

import numpy as np
import pytest
from gymnasium.utils import seeding

from farm.alloc.allocators import Spec, allocator_entry, make_allocator
from farm.alloc.evaluation.rollout import play
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import Layout, episode_end, observe, start_densities, step
from farm.alloc.game.lattice import memo_client
from farm.alloc.game.model import EngagementModel
from farm.alloc.intruders import (
    intruder_names,
    register_intruders,
    unregister_intruders,
)
from farm.alloc.intruders.exact_search import (
    ScriptedIntruders,
    cell_options,
    exact_response,
    tree_bound,
)
from farm.core.errors import ConfigError
from farm.studies.exploit import COLUMNS, TIMINGS, exact_responses, response_table

SETTINGS = {"n_defenders": 4, "n_intruders": 8, "games": 4, "team_sizes": "lattice", "c_capture": 1.5}
SMALL = AllocConfig(grid_size=3, **SETTINGS)
TWO = AllocConfig(grid_size=2, **SETTINGS)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store holding the lattice of SMALL and TWO (the same game settings): its path."""
    path = tmp_path_factory.mktemp("exact") / "s.sqlite"
    client, _, _ = memo_client([SMALL], "local", path)
    client.close()
    return path


@pytest.fixture(scope="module")
def client(store):
    """An in-process client over the store, its lattice in memory."""
    client, _, _ = memo_client([SMALL], "local", store)
    yield client
    client.close()


# ----------------------------------------------------------------------------- a plain enumeration
def options_by_hand(n, cell, shares):
    """A cell's (up, straight, down) share counts on the grid 1/shares, in the documented tie order."""
    row = cell // n
    out = [(u, s, shares - u - s) for u in range(shares + 1) for s in range(shares + 1 - u)
           if (row > 0 or u == 0) and (row < n - 1 or shares - u - s == 0)]
    return sorted(out, key=lambda o: (-o[1], -o[0]))


def plain_best(config, policy, model, D, I, steps, objective, shares):
    """(the least objective summed to the episode's end from (D, I) after `steps` steps, the
    routings reaching it): every pure or split routing of every step tried, one step at a time,
    no memo; ties to the first in itertools.product's order."""
    n, layout = config.grid_size, Layout(config.grid_size)
    cells = [c for c in range(n * n) if I[c] > 0 and c % n > 0]
    best = None
    for combo in itertools.product(*[options_by_hand(n, c, shares) for c in cells]):
        up, down = np.zeros(n * n), np.zeros(n * n)
        for c, (u, _, d) in zip(cells, combo):
            up[c], down[c] = u / shares, d / shares
        action, _ = policy.predict(observe(D[None], I[None])[0], deterministic=True)
        r = step(layout, config, model, D[None], I[None], np.asarray(action, dtype=np.float64)[None],
                 lambda moved, intruders, up=up, down=down: (up[None], down[None]))
        gain = r.eliminated[0] if objective == "eliminated" else r.reward[0]
        terminated, truncated = episode_end(config, np.array([steps + 1]), r.remaining)
        if terminated[0] or truncated[0]:
            value, later = gain, []
        else:
            rest, later = plain_best(config, policy, model, r.D[0], r.I[0], steps + 1, objective, shares)
            value = gain + rest
        if best is None or value < best[0]:
            best = (value, [(up, down)] + later)
    return best


def start(config, seed):
    """An episode's start, drawn here as play() draws it."""
    shares = seeding.np_random(seed)[0].dirichlet(np.ones(config.grid_size))
    D, I = start_densities(Layout(config.grid_size), shares[None])
    return D[0], I[0]


def forward(config, policy, model, seed, routings):
    """The summary (return, eliminated, breached, length) of an episode played with these routings."""
    layout = Layout(config.grid_size)
    D, I = start(config, seed)
    totals = np.zeros(3)
    for up, down in routings:
        action, _ = policy.predict(observe(D[None], I[None])[0], deterministic=True)
        r = step(layout, config, model, D[None], I[None], np.asarray(action, dtype=np.float64)[None],
                 lambda moved, intruders, up=up, down=down: (up[None], down[None]))
        totals += (r.reward[0], r.eliminated[0], r.breach[0])
        D, I = r.D[0], r.I[0]
    return {"return": float(totals[0]), "eliminated": float(totals[1]), "breached": float(totals[2]),
            "length": len(routings)}


CASES = [(SMALL, "intercept", "eliminated", 1), (SMALL, "spread_evenly", "return", 1),
         (SMALL, "mmr", "eliminated", 1), (TWO, "intercept", "eliminated", 2), (TWO, "spread_evenly", "return", 2)]


@pytest.mark.parametrize("config, name, objective, shares", CASES)
def test_the_search_is_a_plain_recursive_enumeration_to_the_bit(client, config, name, objective, shares):
    policy = make_allocator(name, config, client)
    model = EngagementModel(config, client, False)
    for seed in (3, 11):
        got = exact_response(config, policy, client, seed, objective=objective, shares=shares)
        value, routings = plain_best(config, policy, model, *start(config, seed), 0, objective, shares)
        assert got.value == value
        assert len(got.routings) == len(routings)
        for (up, down), (want_up, want_down) in zip(got.routings, routings):
            assert up.tobytes() == want_up.tobytes() and down.tobytes() == want_down.tobytes()
        assert got.summary == forward(config, policy, model, seed, routings)
        assert got.nodes <= tree_bound(config, start(config, seed)[1], shares)[0]


def test_the_options_of_a_cell_in_their_tie_order():
    assert cell_options((True, True, True)).tolist() == [[0, 1, 0], [1, 0, 0], [0, 0, 1]]
    assert cell_options((False, True, True)).tolist() == [[0, 1, 0], [0, 0, 1]]
    halves = cell_options((True, True, True), 2)
    assert halves.tolist() == [[0, 1, 0], [0.5, 0.5, 0], [0, 0.5, 0.5], [1, 0, 0], [0.5, 0, 0.5], [0, 0, 1]]
    assert np.all(halves.sum(axis=1) == 1.0)


# ----------------------------------------------------------------------------- the replay
@pytest.fixture
def scripted():
    register_intruders("scripted_for_test", ScriptedIntruders.make, kind="heuristic")
    yield "scripted_for_test"
    unregister_intruders("scripted_for_test")


@pytest.mark.parametrize("name", ["intercept", "receding_horizon", "stay_at_base"])
@pytest.mark.parametrize("shares", [1, 2])
def test_replaying_the_routings_through_play_gives_the_summary_to_the_bit(client, scripted, name, shares):
    policy = make_allocator(name, SMALL, client)
    for seed in (0, 7):
        got = exact_response(SMALL, policy, client, seed, shares=shares)
        replay = SMALL.model_copy(update={"intruders": scripted, "information": "follower",
                                          "intruder_options": {"routings": got.routings}})
        played = play(replay, policy, client, 1, seed)[0]
        assert {k: played.summary[k] for k in got.summary} == got.summary


def test_a_map_too_large_is_refused_in_one_line_before_the_search_starts():
    class Never:
        """Neither a client nor an allocator that may be asked."""

        repeatable = True

        def get_many(self, pairs, estimate=False):
            raise AssertionError("asked")

        def predict(self, obs, deterministic=True):
            raise AssertionError("asked")

    big = AllocConfig(grid_size=5, **SETTINGS)
    with pytest.raises(ConfigError) as e:
        exact_response(big, Never(), Never(), 0)
    assert e.value.field == "max_nodes" and "\n" not in str(e.value) and "5x5" in str(e.value)
    with pytest.raises(ConfigError) as e:  # split routings on 3x3 with a small budget
        exact_response(SMALL, Never(), Never(), 0, shares=2, max_nodes=1000)
    assert e.value.field == "max_nodes"
    bads = (({"objective": "won"}, "objective"), ({"shares": 0}, "shares"), ({"max_nodes": 1.5}, "max_nodes"))
    for bad, field in bads:
        with pytest.raises(ConfigError) as e:
            exact_response(SMALL, Never(), Never(), 0, **bad)
        assert e.value.field == field and "\n" not in str(e.value)


def test_the_ray_fan_out_refuses_a_large_map_before_ray_starts(tmp_path):
    # this test runs without Ray: $RAY_ADDRESS names a closed port, which a start would fail on
    big = AllocConfig(grid_size=5, **SETTINGS)
    with pytest.raises(ConfigError) as e:
        exact_responses(big, Spec(allocator_entry("intercept")), 2, 0, store=tmp_path / "s.sqlite",
                        show_progress=False)
    assert e.value.field == "max_nodes"
    with pytest.raises(ConfigError) as e:
        exact_responses(SMALL, Spec(allocator_entry("intercept")), 0, 0, store=tmp_path / "s.sqlite")
    assert e.value.field == "episodes"


def test_the_search_is_never_worse_than_a_heuristic_of_the_registry(client):
    """Pure routings against the pure heuristics, routings on halves against every one (split_away
    sends halves); the search's sums run from the episode's end, play's from its start, hence 1e-12."""
    pure = {"drift", "fewest_ahead", "least_defended"}  # at vertical_drift 0, drift goes straight
    assert {"drift", "fewest_ahead", "least_defended", "split_away"} <= set(intruder_names(("law", "heuristic")))
    for name in ("intercept", "spread_evenly", "mmr"):
        policy = make_allocator(name, SMALL, client)
        for seed in range(4):
            best = exact_response(SMALL, policy, client, seed)
            halves = exact_response(SMALL, policy, client, seed, shares=2)
            assert halves.value <= best.value
            for intruders in intruder_names(("law", "heuristic")):
                config = SMALL.model_copy(update={"intruders": intruders, "information": "follower"})
                played = play(config, policy, client, 1, seed)[0].summary["eliminated"]
                assert halves.summary["eliminated"] <= played + 1e-12, (name, seed, intruders)
                if intruders in pure:
                    assert best.summary["eliminated"] <= played + 1e-12, (name, seed, intruders)


# ----------------------------------------------------------------------------- on Ray
@pytest.mark.ray
@pytest.mark.slow
def test_on_ray_the_table_is_the_plain_enumeration_and_the_same_whatever_the_workers(ray_local, store, client):
    spec = Spec(allocator_entry("intercept"))
    here = response_table(SMALL, spec, client, 5, 20)
    tables = [exact_responses(SMALL, spec, 5, 20, workers=w, per_task=p, store=store, show_progress=False)
              for w, p in ((1, 1), (2, 1), (2, 3))]
    assert list(here.columns) == list(COLUMNS)
    same = [c for c in COLUMNS if c not in TIMINGS]
    for table in tables:
        assert table[same].equals(here[same])
        assert list(table["episode"]) == list(range(5)) and list(table["seed"]) == list(range(20, 25))
    assert [t.attrs["info"]["workers"] for t in tables] == [1, 2, 2]
    policy, model = make_allocator("intercept", SMALL, client), EngagementModel(SMALL, client, False)
    for k, seed in enumerate((20, 21)):
        _, routings = plain_best(SMALL, policy, model, *start(SMALL, seed), 0, "eliminated", 1)
        want = forward(SMALL, policy, model, seed, routings)
        assert {m: tables[1][m][k] for m in ("return", "eliminated", "breached", "length")} == want


@pytest.mark.ray
def test_on_ray_split_routings_and_the_return_objective(ray_local, store, client):
    spec = Spec(allocator_entry("spread_evenly"))
    options = {"objective": "return", "shares": 2}
    here = response_table(TWO, spec, client, 3, 5, **options)
    there = exact_responses(TWO, spec, 3, 5, workers=2, store=store, show_progress=False, **options)
    same = [c for c in COLUMNS if c not in TIMINGS]
    assert there[same].equals(here[same])
