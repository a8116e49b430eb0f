"""`search` intruders (farm.alloc.intruders.searching): with one member in their model they play the
exact search's routings to the bit; against a mixture their play is worth the value of a plain
recursive enumeration written here (no memo, no bound), no more than the follower told the member
and no less than intruders modelling one member; they play the same in a mixture of intruders, in
the env and after a saved episode is resumed; bad options are one line. Small real games (4 a case)
in a store under tmp_path."""

import numpy as np
import pytest

from farm.alloc.allocators import make_allocator, register_allocator, unregister_allocator
from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.evaluation.rollout import play
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    check_actions,
    episode_end,
    move_defenders,
    move_probabilities,
    observe,
    resolve,
    start_densities,
)
from farm.alloc.game.lattice import memo_client
from farm.alloc.game.model import EngagementModel
from farm.alloc.intruders import make_intruders
from farm.alloc.intruders.exact_search import cell_options, episode_start, exact_response
from farm.core.config import first_line
from farm.core.errors import ConfigError

SETTINGS = {"n_defenders": 4, "n_intruders": 8, "games": 4, "team_sizes": "lattice", "c_capture": 1.5}
SMALL = AllocConfig(grid_size=3, information="follower", **SETTINGS)
EPISODES, SEED = 4, 300


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """An in-process client over a store holding SMALL's lattice, in memory."""
    path = tmp_path_factory.mktemp("searching") / "s.sqlite"
    client, _, _ = memo_client([SMALL], "local", path)
    yield client
    client.close()


class FirstThen:
    """A test allocator: `first`'s move while every defender is at the base, `then`'s after: it
    moves as `first` at an episode's first step, so the intruders cannot tell the two apart there."""

    def __init__(self, config, client, first="intercept", then="spread_evenly"):
        self.first, self.then = make_allocator(first, config, client), make_allocator(then, config, client)
        D0, _ = start_densities(Layout(config.grid_size), np.ones((1, config.grid_size)) / config.grid_size)
        self.start = D0[0].astype(np.float32)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        at_base = np.array_equal(np.asarray(obs)[: len(self.start)], self.start)
        return (self.first if at_base else self.then).predict(obs, deterministic=deterministic)


@pytest.fixture(scope="module", autouse=True)
def first_then():
    register_allocator("first_then", FirstThen, kind="baseline", reference=False)
    yield
    unregister_allocator("first_then")


def searching(models, weights=None, objective="eliminated"):
    """SMALL with search intruders modelling the allocators `models` (specs)."""
    return SMALL.model_copy(update={"intruders": "search", "intruder_options": {
        "allocators": models, "weights": weights, "objective": objective}})


def played(config, allocator, client, measure="eliminated"):
    """(EPISODES,) float64: the allocator's measure in config's episodes SEED, SEED + 1, ..."""
    policy = make_allocator(allocator["policy"], config, client, **allocator.get("options", {}))
    return np.array([e.summary[measure] for e in play(config, policy, client, EPISODES, SEED)])


# ----------------------------------------------------------------------------- a plain enumeration
def routings_by_hand(I, n):
    """Every pure routing of intruders I: (N^2,) float64 as (up, down) pairs, in any order."""
    cells = [c for c in range(n * n) if I[c] > 0 and c % n > 0]
    out = [(np.zeros(n * n), np.zeros(n * n))]
    for c in cells:
        row, grown = c // n, []
        for up, down in out:
            for u, _, d in cell_options((row > 0, True, row < n - 1)):
                a, b = up.copy(), down.copy()
                a[c], b[c] = u, d
                grown.append((a, b))
        out = grown
    return out


def value_by_hand(config, client, models, D, I, t):
    """The defenders' least expected eliminated mass from (D, I) after t steps against the members
    models ([(policy, weight)], all still possible), the intruders seeing each move: recursion over
    every routing, no memo, no bound."""
    layout, n = Layout(config.grid_size), config.grid_size
    model = EngagementModel(config, client, False)
    if not any(I[c] > 0 and c % n > 0 for c in range(n * n)):
        groups = {D.tobytes(): (D, models)}
    else:
        groups = {}
        for policy, w in models:
            action, _ = policy.predict(observe(D[None], I[None])[0], deterministic=True)
            p = move_probabilities(layout, config, check_actions(action, (len(layout.src),))[None])
            moved = move_defenders(layout, D[None], p)[0]
            groups.setdefault(moved.tobytes(), (moved, []))[1].append((policy, w))
    total = sum(w for _, w in models)
    value = 0.0
    for moved, members in groups.values():
        best = np.inf
        for up, down in routings_by_hand(I, n):
            r = resolve(layout, config, model, moved[None], I[None], (up[None], down[None]))
            v = float(r.eliminated[0])
            ended = np.any(episode_end(config, np.array([t + 1]), r.remaining))
            if not ended:
                v += value_by_hand(config, client, members, r.D[0], r.I[0], t + 1)
            best = min(best, v)
        value += sum(w for _, w in members) / total * best
    return value


# ----------------------------------------------------------------------------- the tests
@pytest.mark.parametrize("objective", ["eliminated", "return"])
def test_modelling_one_allocator_they_play_the_exact_searchs_routings(client, objective):
    for allocator in ("intercept", "spread_evenly"):
        config = searching([{"policy": allocator}], objective=objective)
        got = played(config, {"policy": allocator}, client, objective)
        policy = make_allocator(allocator, SMALL, client)
        want = [exact_response(SMALL, policy, client, SEED + k, objective=objective).summary[objective]
                for k in range(EPISODES)]
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("then", ["first_then", "spread_evenly"])  # the same first move then apart; apart
def test_against_a_mixture_they_are_worth_a_plain_enumerations_value(client, then):
    members = [{"policy": "intercept"}, {"policy": then}]
    weights = np.array([0.3, 0.7])
    config = searching(members, weights.tolist())
    got = np.array([played(config, m, client) for m in members])  # (members, episodes)
    policies = [make_allocator(m["policy"], SMALL, client) for m in members]
    for k in range(EPISODES):
        D, I = episode_start(SMALL, SEED + k)
        by_hand = value_by_hand(SMALL, client, list(zip(policies, weights)), D, I, 0)
        assert weights @ got[:, k] == pytest.approx(by_hand, abs=1e-12)
    # told the member drawn, the follower does at least as well; modelling one member, no better
    told = np.array([[exact_response(SMALL, p, client, SEED + k).summary["eliminated"] for k in range(EPISODES)]
                     for p in policies])
    assert np.all(weights @ got >= weights @ told - 1e-12)
    if then == "first_then":
        assert np.any(weights @ got > weights @ told + 1e-6)  # the shared first move hides the member there
    else:
        np.testing.assert_allclose(weights @ got, weights @ told, rtol=0, atol=1e-12)  # the first move tells it
    for alone in members:
        one = np.array([played(searching([alone]), m, client) for m in members])
        assert np.all(weights @ got <= weights @ one + 1e-12)


def test_in_a_mixture_of_intruders_in_the_env_and_resumed_they_play_the_same(client):
    members = [{"policy": "intercept"}, {"policy": "spread_evenly"}]
    config = searching(members, [0.1, 0.9])
    want = played(config, {"policy": "intercept"}, client)  # its first move tells the member: the best reply to it
    np.testing.assert_array_equal(want, played(searching(members[:1]), {"policy": "intercept"}, client))
    assert np.any(want != played(searching(members[1:]), {"policy": "intercept"}, client))
    mixed = SMALL.model_copy(update={"intruders": "mixture", "intruder_options": {
        "members": [{"intruders": "search", "options": {"allocators": members, "weights": [0.1, 0.9]}}],
        "draw": "episode"}})
    np.testing.assert_array_equal(played(mixed, {"policy": "intercept"}, client), want)
    policy = make_allocator("intercept", SMALL, client)
    for k in range(2):
        env = SwarmAllocationEnv(config, client=client)
        obs, _ = env.reset(seed=SEED + k)
        done, steps = False, 0
        while not done:
            if steps == 1:  # the episode saved and resumed in a new env mid-way
                state = env.get_state()
                env = SwarmAllocationEnv(config, client=client)
                env.set_state(state)
                assert env.get_state()["intruder_draw"] == state["intruder_draw"]  # the members it still holds
            obs, _, terminated, truncated, info = env.step(policy.predict(obs, deterministic=True)[0])
            done, steps = terminated or truncated, steps + 1
        assert info["eliminated"] == pytest.approx(want[k], abs=1e-12)


@pytest.mark.parametrize("options, words", [
    ({"allocators": ["intercept"], "objective": "style"}, "intruder_options.objective"),
    ({"allocators": [{"policy": "mixture", "options": {"members": ["intercept", "transport"]}}]},
     "intruder_options.allocators: mixture draws its moves"),
    ({"allocators": []}, "intruder_options.members"),
    ({"allocators": ["intercept"], "depth": 2}, "intruder_options: search has no option 'depth'"),
])
def test_bad_options_are_one_line(client, options, words):
    with pytest.raises(ConfigError) as e:
        make_intruders("search", SMALL, client, **options)
    assert words in first_line(e.value) and "\n" not in str(e.value)


def test_without_a_client_they_are_refused_in_one_line():
    with pytest.raises(ConfigError, match="intruder_options: search intruders plan on a capture-time client"):
        make_intruders("search", SMALL, allocators=["intercept"])


@pytest.mark.parametrize("scenario", ["outnumbered_5x5", "wide_front_8x8"])
def test_on_a_map_whose_tree_does_not_fit_they_are_refused_before_a_step_and_before_a_training(scenario, tmp_path):
    """As docs/model.md says: the env refuses them when made, and a training config when checked,
    before anything is written."""
    from farm.alloc.envs.defenders import SwarmAllocationEnv
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.alloc.training.config import TrainConfig, check_trainable

    n = SCENARIOS[scenario].config().grid_size
    words = f"intruder_options: search: its tree on this {n}x{n} map could hold more than"
    env = SCENARIOS[scenario].config(intruders="search", intruder_options={"allocators": ["intercept"]})
    with pytest.raises(ConfigError, match=words):
        SwarmAllocationEnv(env)
    with pytest.raises(ConfigError, match=words):
        intruders = {"intruders": "search", "intruder_options": {"allocators": ["intercept"]}}
        check_trainable(TrainConfig(name="t", scenario=scenario, algo="ppo", env=intruders))
    assert not list(tmp_path.iterdir())
