"""The allocation MDP (docs/model.md section 5) as a gymnasium env."""

import warnings

import gymnasium
import numpy as np
import pytest

import farm.alloc as alloc
from farm.alloc import AllocConfig, SwarmAllocationEnv, moves, n_actions
from farm.alloc.allocators import allocator_names, make_allocator
from farm.service import CaptureTimeClient

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)


def make(store, **kw):
    return SwarmAllocationEnv(AllocConfig(**{**SMALL, **kw}), store=store)


@pytest.mark.parametrize("n", [3, 4, 5, 7])
def test_action_count(n):
    assert n_actions(n) == 4 * 4 + 6 * 4 * (n - 2) + 9 * (n - 2) ** 2
    assert len(moves(n)[0]) == n_actions(n)
    assert SwarmAllocationEnv(AllocConfig(grid_size=n), client=object()).action_space.shape == (n_actions(n),)
    assert n_actions(3) == 49


@pytest.mark.parametrize("action_map", ["softmax", "shifted"])
@pytest.mark.parametrize("n", [3, 5])
def test_transition_matrix_is_column_stochastic(n, action_map, rng):
    env = SwarmAllocationEnv(AllocConfig(grid_size=n, action_map=action_map), client=object())
    feasible = np.zeros((n * n, n * n), bool)
    for j in range(n * n):
        r, c = divmod(j, n)
        for i in range(n * n):
            rr, cc = divmod(i, n)
            feasible[i, j] = abs(rr - r) <= 1 and abs(cc - c) <= 1
    for a in [rng.uniform(-1, 1, n_actions(n)) for _ in range(20)] + [-np.ones(n_actions(n)), np.ones(n_actions(n))]:
        T = env.transition_matrix(a)
        np.testing.assert_allclose(T.sum(axis=0), 1.0, atol=1e-12)
        assert np.all(T[~feasible] == 0.0) and np.all(T >= 0)


def test_registered_and_checkers_pass_without_warnings(store):
    env = gymnasium.make(alloc.ENV_ID, store=store, **SMALL)
    assert isinstance(env.unwrapped, SwarmAllocationEnv)
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gymnasium.make(alloc.ENV_ID, store=store, **SMALL).unwrapped)
        sb3_check_env(gymnasium.make(alloc.ENV_ID, store=store, **SMALL).unwrapped, warn=True)
    assert [str(w.message) for w in caught] == []


def test_reset_start_state(store):
    env = make(store)
    obs, _ = env.reset(seed=3)
    D, I = obs[:9].reshape(3, 3), obs[9:].reshape(3, 3)
    assert D[1, 0] == 1.0 and D.sum() == 1.0
    assert np.all(I[:, :2] == 0) and I[:, 2].sum() == pytest.approx(1.0, abs=1e-6)
    assert obs.dtype == np.float32
    other, _ = env.reset(seed=4)
    assert not np.array_equal(obs, other)


def test_mass_conservation_and_monotone_intruders(store, rng):
    env = make(store, vertical_drift=0.2)
    for ep in range(4):
        env.reset(seed=ep)
        prev_total = env.I.sum() + env.breached + env.eliminated
        prev_I = env.I.sum()
        for _ in range(env.config.max_steps):
            _, _, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
            assert env.D.sum() == pytest.approx(1.0, abs=1e-12) and np.all(env.D >= 0)
            assert env.I.sum() <= prev_I + 1e-12
            assert env.I.sum() + env.breached + env.eliminated == pytest.approx(prev_total, abs=1e-12)
            prev_I = env.I.sum()
            if term or trunc:
                break


def test_same_seed_same_episode(store):
    def episode(seed):
        env = make(store)
        env.reset(seed=seed)
        out = []
        rng = np.random.default_rng(seed)
        for _ in range(env.config.max_steps):
            o, r, term, trunc, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
            out.append((o.copy(), r))
            if term or trunc:
                break
        return out

    a, b = episode(5), episode(5)
    assert len(a) == len(b) and all(np.array_equal(x[0], y[0]) and x[1] == y[1] for x, y in zip(a, b))


def test_reward_by_hand(store):
    """One engineered step checked against docs/model.md's formula with the service's numbers
    (the earlier, conditional capture score; tests/test_capture_score.py checks the expected one)."""
    env = make(store, c_distribution=0.7, c_capture=1.5, breach_penalty=2.0, capture_time_norm=8.0,
               capture_score="conditional")
    env.reset(seed=0)
    env.D = np.zeros(9)
    env.D[4] = 0.6  # centre: 6 defenders
    env.D[3] = 0.4  # base: 4 defenders
    env.I = np.zeros(9)
    env.I[5] = 0.5  # right of centre: moves into the centre
    env.I[3] = 0.2  # at the left edge: breaches
    env.I[2] = 0.3  # top right: moves to top centre, no defenders there
    stay = np.where(env.src == env.dst, 1.0, -1.0)  # softmax(5*a): stay with probability e^10/(e^10+k-1)
    p = env.move_probabilities(stay)
    D_next = np.bincount(env.dst, weights=p * env.D[env.src], minlength=9)
    _, r, _, _, info = env.step(stay)
    client = CaptureTimeClient(env.config.game_settings(), local_store=store)
    v = client.get(int(round(D_next[4] * 10)), int(round(0.5 * 5)))
    remaining_centre = 0.5 * (1 - v.frac_captured_tau)
    t = v.mean_capture.mean if np.isfinite(v.mean_capture.mean) else env.config.t_max
    expected = -0.7 * (remaining_centre + 0.3) + 1.5 * 0.5 * max(0.0, 1 - t / 8.0) - 2.0 * 0.2
    assert info["breached_step"] == pytest.approx(0.2)
    assert info["engaged_cells"] == 1
    assert r == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("name", sorted(allocator_names("baseline")))
def test_baselines_act_like_models(store, name):
    env = make(store)
    policy = make_allocator(name, env.config)
    obs, _ = env.reset(seed=1)
    action, _ = policy.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    if name == "stay_at_base":
        env.step(action)
        assert env.D[3] > 0.99


@pytest.mark.parametrize("bad,field", [({"grid_size": 1}, "grid_size"), ({"n_defenders": 0}, "n_defenders"),
                                      ({"c_capture": -1}, "c_capture"), ({"colour": 1}, "colour"),
                                      ({"action_map": "tanh"}, "action_map")])
def test_bad_config_names_the_field(bad, field):
    from pydantic import ValidationError

    with pytest.raises(ValidationError) as err:
        AllocConfig(**bad)
    assert err.value.errors()[0]["loc"][0] == field


def test_estimates_answer_first_visits_and_are_counted(tmp_path):
    """With estimates on, an engaged cell whose team sizes were never computed takes the
    service's interpolation of computed neighbours (its captured fraction removes the mass)
    and is counted; with estimates off the same step waits for the exact value."""
    store = str(tmp_path / "store.sqlite")
    cfg = AllocConfig(**SMALL)
    client = CaptureTimeClient(cfg.game_settings(), local_store=store)
    client.get_many([(3, 1), (3, 2), (5, 1), (5, 2)])  # neighbours of (4, 2)

    def one_step(estimates):
        env = SwarmAllocationEnv(cfg, client=CaptureTimeClient(client.settings, local_store=store), estimates=estimates)
        env.reset(seed=0)
        env.D, env.I = np.zeros(9), np.zeros(9)
        env.D[4], env.D[3] = 0.4, 0.6  # 4 defenders stay in the centre
        env.I[5] = 0.4  # 2 intruders move into it
        stay = np.where(env.src == env.dst, 1.0, -1.0)
        _, _, _, _, info = env.step(stay)
        return env, info

    env, info = one_step(True)
    guess = env.client.get_many([(4, 2)], estimate=True)[0]
    assert guess.estimate and info["estimates"] == 1 and (env.engagements, env.estimated) == (1, 1)
    assert env.I[4] == pytest.approx(0.4 * (1 - guess.frac_captured_tau), abs=1e-12)
    env, info = one_step(False)
    assert info["estimates"] == 0 and (env.engagements, env.estimated) == (1, 0)
