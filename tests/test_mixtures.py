"""Mixed strategies: the allocators' and the intruders' `mixture`, drawn per episode or per step from
each episode's own generator, so a mixture's episodes are its members' episodes and do not depend
on the batching."""

import numpy as np
import pytest
from gymnasium.utils import seeding
from helpers import Answers

from farm.alloc.allocators import make_allocator
from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.envs.vector import SwarmAllocationVectorEnv
from farm.alloc.evaluation.rollout import play
from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

SEED, EPISODES = 1000, 8


def config(**settings):
    return AllocConfig(grid_size=3, n_defenders=4, n_intruders=100, c_capture=1.5, **settings)


def drawn(weights, episodes=EPISODES, seed=SEED):
    """The member each episode of play() draws per episode: after its start, from its generator."""
    out = []
    for k in range(episodes):
        rng = seeding.np_random(seed + k)[0]
        rng.dirichlet(np.ones(3))
        out.append(int(rng.choice(len(weights), p=np.asarray(weights) / np.sum(weights))))
    return out


def summaries(episodes):
    return [e.summary for e in episodes]


def test_an_allocator_mixture_drawn_per_episode_plays_its_members_episodes():
    cfg, client = config(), Answers()
    members = ["stay_at_base", "spread_evenly", "intercept"]
    weights = [0.2, 0.3, 0.5]
    mixed = play(cfg, make_allocator("mixture", cfg, client, members=members, weights=weights), client, EPISODES, SEED)
    alone = {m: play(cfg, make_allocator(m, cfg, client), client, EPISODES, SEED) for m in members}
    picks = drawn(weights)
    assert len(set(picks)) > 1
    assert summaries(mixed) == [alone[members[j]][k].summary for k, j in enumerate(picks)]
    # batching does not matter: the second half played alone draws the same members
    half = play(cfg, make_allocator("mixture", cfg, client, members=members, weights=weights), client, 4, SEED + 4)
    assert summaries(half) == summaries(mixed)[4:]


def test_a_mixture_of_one_weight_is_that_member_to_the_bit():
    cfg, client = config(), Answers()
    mixed = play(cfg, make_allocator("mixture", cfg, client, members=["intercept", "spread_evenly"], weights=[1, 0],
                                  draw="step"), client, EPISODES, SEED)
    assert summaries(mixed) == summaries(play(cfg, make_allocator("intercept", cfg, client), client, EPISODES, SEED))


def test_an_intruder_mixture_in_the_env_the_batched_env_and_play():
    members = ["fewest_ahead", "split_away", "drift"]
    weights = [0.4, 0.4, 0.2]
    cfg = config(intruders="mixture", intruder_options={"members": members, "weights": weights})
    client = Answers()
    policy = make_allocator("spread_evenly", cfg, client)
    mixed = play(cfg, policy, client, EPISODES, SEED)
    picks = drawn(weights)
    for k, j in enumerate(picks):
        alone = play(config(intruders=members[j]), policy, client, 1, SEED + k)[0]
        assert alone.summary == mixed[k].summary
    # the single env and the batched env draw the same members
    env = SwarmAllocationEnv(cfg, client=client)
    venv = SwarmAllocationVectorEnv(cfg, num_envs=EPISODES, client=client)
    obs_b, _ = venv.reset(seed=SEED)
    singles = [env.reset(seed=SEED + k)[0] for k in range(1)]
    assert np.array_equal(singles[0], obs_b[0])
    returns = np.zeros(EPISODES)
    done = np.zeros(EPISODES, dtype=bool)
    while not done.all():
        actions = np.stack([policy.predict(o)[0] for o in obs_b])
        obs_b, r, term, trunc, _ = venv.step(actions)
        returns += np.where(done, 0.0, r)
        done |= term | trunc
    assert np.allclose(returns, [e.summary["return"] for e in mixed], rtol=0, atol=0)


def test_an_env_with_an_intruder_mixture_resumes_its_draw():
    cfg = config(intruders="mixture", intruder_options={"members": ["fewest_ahead", "split_away"], "draw": "step"})
    client = Answers()
    policy = make_allocator("intercept", cfg, client)
    a, b = SwarmAllocationEnv(cfg, client=client), SwarmAllocationEnv(cfg, client=client)
    obs, _ = a.reset(seed=3)
    obs, *_ = a.step(policy.predict(obs)[0])
    state = a.get_state()
    b.set_state(state)
    b_obs = obs
    for _ in range(2):
        action = policy.predict(obs)[0]
        obs, r1, *_ = a.step(action)
        b_obs, r2, *_ = b.step(action)
        assert np.array_equal(obs, b_obs) and r1 == r2


@pytest.mark.parametrize("options, words", [
    ({"members": []}, "mixture.members: a non-empty list"),
    ({"members": ["intercept"], "weights": [1, 2]}, "mixture.weights: 1 numbers"),
    ({"members": ["intercept", "mmr"], "weights": [-1, 2]}, "mixture.weights"),
    # booleans are not weights (refused at any depth), and a sum that overflows is no sum
    ({"members": ["intercept", "mmr"], "weights": [True, False]}, "mixture.weights: 2 numbers"),
    ({"members": ["intercept", "mmr"], "weights": [1e308, 1e308]}, "positive finite sum"),
    ({"members": ["intercept", "mmr"], "weights": "0.5,0.5"}, "mixture.weights: 2 numbers"),
    ({"members": ["intercept"], "draw": "sometimes"}, "mixture.draw: one of episode, step"),
    ({"members": [{"policy": "intercept", "depth": 2}]}, "mixture.members: member 0 is not a name"),
    ({"members": ["nobody"]}, "unknown allocator 'nobody'"),
])
def test_a_bad_mixture_is_one_line_naming_its_field(options, words):
    with pytest.raises(ConfigError) as e:
        make_allocator("mixture", config(), Answers(), **options)
    assert words in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("weights", [[0], [True], [1e308, 1e308]])
def test_a_bad_intruder_mixture_names_intruder_options(weights):
    members = ["drift", "fewest_ahead"][:len(weights)]
    with pytest.raises(ConfigError, match=r"intruder_options.weights"):
        SwarmAllocationEnv(config(intruders="mixture", intruder_options={"members": members, "weights": weights}),
                           client=Answers())


def test_the_intruders_env_draws_its_mixture_opponent_per_episode():
    """Against a mixture drawn per episode, the follower's first observation is the drawn member's move."""
    from farm.alloc.envs.intruders import SwarmIntruderEnv, SwarmIntruderVectorEnv
    from farm.alloc.game.dynamics import Layout, defenders_move, observe

    cfg, client = config(), Answers()
    members, weights = ["stay_at_base", "spread_evenly", "intercept"], [0.3, 0.3, 0.4]
    options = {"members": members, "weights": weights}
    env = SwarmIntruderEnv(cfg, opponent="mixture", opponent_options=options, client=client)
    venv = SwarmIntruderVectorEnv(cfg, num_envs=EPISODES, opponent="mixture", opponent_options=options, client=client)
    batch, _ = venv.reset(seed=SEED)
    layout = Layout(3)
    for k, j in enumerate(drawn(weights)):
        obs, _ = env.reset(seed=SEED + k)
        start = seeding.np_random(SEED + k)[0].dirichlet(np.ones(3))
        D, I = np.zeros(9), np.zeros(9)
        D[layout.base], I[layout.right] = 1.0, start
        action = make_allocator(members[j], cfg, client).predict(observe(D[None], I[None])[0])[0]
        moved = defenders_move(layout, cfg, D[None], np.asarray(action, dtype=np.float64)[None])[0]
        assert np.array_equal(obs, observe(moved[None], I[None])[0]) and np.array_equal(batch[k], obs)
    state = env.get_state()
    assert "opponent_draw" in state
    again = SwarmIntruderEnv(cfg, opponent="mixture", opponent_options=options, client=client)
    again.reset(seed=0)
    again.set_state(state)
    action = np.zeros(env.action_space.shape)
    assert env.step(action)[1] == again.step(action)[1]


def test_a_mixture_of_mean_moves_plays_the_members_averaged_move_probabilities():
    """draw: mean moves each cell's defenders by the weighted mean of the members' move
    probabilities (to the action map's floor), deterministically; the intruders' by the mean routing."""
    from farm.alloc.game.dynamics import Layout, move_probabilities, observe

    cfg, client = config(action_map="shifted"), Answers()
    members, weights = ["intercept", "spread_evenly"], [0.25, 0.75]
    mean = make_allocator("mixture", cfg, client, members=members, weights=weights, draw="mean")
    layout = Layout(3)
    rng = np.random.default_rng(0)
    for _ in range(5):
        D, I = rng.random(9), rng.random(9) * (rng.random(9) < 0.5)
        D /= D.sum()
        obs = observe(D[None], I[None])[0]
        want = sum(w * move_probabilities(layout, cfg, np.asarray(make_allocator(m, cfg, client).predict(obs)[0],
                                                                  dtype=np.float64)[None])[0]
                   for m, w in zip(members, weights))
        got = move_probabilities(layout, cfg, np.asarray(mean.predict(obs)[0], dtype=np.float64)[None])[0]
        assert np.allclose(got, want, atol=1e-6)
        assert np.array_equal(mean.predict(obs)[0], mean.predict(obs)[0])
    played = play(cfg, mean, client, 4, SEED)
    assert summaries(played) == summaries(play(cfg, mean, client, 4, SEED))
    from farm.alloc.intruders import make_intruders

    side = make_intruders("mixture", cfg, members=["fewest_ahead", "drift"], weights=[0.5, 0.5], draw="mean")
    D, I = rng.random((2, 9)), rng.random((2, 9))
    up, down = side.routing(D, I)
    a, b = make_intruders("fewest_ahead", cfg).routing(D, I), make_intruders("drift", cfg).routing(D, I)
    assert np.allclose(up, 0.5 * a[0] + 0.5 * b[0]) and np.allclose(down, 0.5 * a[1] + 0.5 * b[1])
