"""The batched allocation env (farm.alloc.envs.vector) and its stable-baselines3 adapter
(farm.alloc.envs.sb3_vec): bit for bit the single env's episodes, one lookup a step, gymnasium's
SAME_STEP autoreset, exact save and restore, SB3's conventions. No Ray: an in-process client."""

import pickle

import gymnasium
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from helpers import assert_same

import farm.alloc  # noqa: F401  (registers the ids)
from farm.alloc import SCENARIOS, AllocConfig, SwarmAllocationEnv
from farm.alloc.envs.sb3_vec import SB3VecEnv, make_vec_env
from farm.alloc.envs.vector import INFO_KEYS, SwarmAllocationVectorEnv
from farm.alloc.game.lattice import lattice_pairs
from farm.alloc.game.model import row_sums, segment_sums
from farm.core.errors import ActionError, ConfigError
from farm.service import CaptureTimeClient

GAME = dict(team_sizes="lattice", games=4)
C3 = dict(grid_size=3, n_defenders=20, n_intruders=10, c_capture=1.5, **GAME)
C5 = dict(grid_size=5, n_defenders=30, n_intruders=20, c_capture=1.5, max_steps=16, **GAME)
DRIFT = dict(grid_size=5, n_defenders=20, n_intruders=12, c_capture=1.0, vertical_drift=0.25, max_steps=16, **GAME)
C8 = dict(grid_size=8, n_defenders=64, n_intruders=24, c_capture=1.5, max_steps=6, **GAME)
SHORT = dict(C3, max_steps=2)  # truncated before the intruders are through


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """One in-process client for every config here (their games' settings are the same), its
    lattice computed once."""
    cfg = AllocConfig(**C8)
    c = CaptureTimeClient(cfg.game_settings(), local_store=tmp_path_factory.mktemp("vec") / "s.sqlite")
    c.get_many(sorted(set(lattice_pairs(cfg)) | set(lattice_pairs(AllocConfig(**C5)))))
    yield c
    c.close()


class Counting:
    """A client that counts its get_many calls and the pairs asked."""

    def __init__(self, inner):
        self.inner, self.calls, self.asked = inner, 0, []

    def get_many(self, pairs, **kwargs):
        self.calls += 1
        self.asked.append(list(pairs))
        return self.inner.get_many(self.asked[-1], **kwargs)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def actions_for(space, rng, t):
    """Random actions, every third step sharper (the softmax saturates) and every fifth
    'stay' (long engagements)."""
    a = rng.uniform(-1, 1, space.shape)
    return a * 3 if t % 3 == 0 else a


@pytest.mark.parametrize("kw", [C3, C5, DRIFT], ids=["3x3", "5x5", "5x5-drift"])
@pytest.mark.parametrize("B", [1, 4])
def test_each_batched_episode_is_the_single_env_seeded_s_plus_k(client, kw, B):
    """gymnasium's SyncVectorEnv (SAME_STEP) of single envs is the reference: its env k is a
    SwarmAllocationEnv reset with seed s + k; everything returned must be the same bits, over
    whole episodes and the autoresets between them."""
    cfg = AllocConfig(**kw)
    batched = SwarmAllocationVectorEnv(cfg, num_envs=B, client=client)
    ref = SyncVectorEnv([lambda: SwarmAllocationEnv(cfg, client=client) for _ in range(B)],
                        autoreset_mode=AutoresetMode.SAME_STEP)
    rng = np.random.default_rng(B)
    for out, expected in zip(batched.reset(seed=11), ref.reset(seed=11)):
        assert_same(out, expected)
    ends = 0
    for t in range(3 * cfg.max_steps):
        a = actions_for(batched.action_space, rng, t).astype(np.float32)
        got, want = batched.step(a), ref.step(a)
        for name, x, y in zip(("obs", "reward", "terminated", "truncated", "infos"), got, want):
            assert_same(x, y, f"step {t} {name}")
        ends += int(np.sum(got[2] | got[3]))
    assert ends >= B  # autoresets were crossed
    assert batched.engagements == sum(e.engagements for e in ref.envs) > 0


def test_many_engaged_cells_an_episode_are_summed_as_alone(client):
    """An 8x8 start with defenders in every cell: each episode engages 8 cells at once (numpy's
    pairwise summation's longer blocks), episodes of different starts side by side."""
    cfg = AllocConfig(**C8)
    B = 3
    batched = SwarmAllocationVectorEnv(cfg, num_envs=B, client=client)
    batched.reset(seed=5)
    state = batched.get_state()
    rng = np.random.default_rng(0)
    state["D"] = rng.dirichlet(np.ones(64), size=B) * 0.5 + 0.5 / 64
    state["I"] = np.zeros((B, 64))
    state["I"][:, np.arange(8) * 8 + 6] = rng.dirichlet(np.ones(8), size=B)  # the next column: engaged next step
    batched.set_state(state)
    singles = [SwarmAllocationEnv(cfg, client=client) for _ in range(B)]
    for k, env in enumerate(singles):
        env.reset(seed=5 + k)
        env.D, env.I = state["D"][k].copy(), state["I"][k].copy()
    stay = np.where(batched.layout.src == batched.layout.dst, 1.0, -1.0)
    for t in range(3):
        obs, reward, term, trunc, infos = batched.step(np.tile(stay, (B, 1)))
        for k, env in enumerate(singles):
            o, r, te, tr, info = env.step(stay)
            assert np.array_equal(obs[k], o) and reward[k] == r and (term[k], trunc[k]) == (te, tr)
            assert all(infos[key][k] == info[key] for key, _ in INFO_KEYS)
        if t == 0:
            assert np.all(infos["engaged_cells"] == 8)


def test_row_and_segment_sums_are_each_rows_own_numpy_sum():
    rng = np.random.default_rng(3)
    for width in (1, 5, 9, 64, 200):
        X = rng.uniform(0, 1, (7, width))
        assert all(s == X[k].sum() for k, s in enumerate(row_sums(X)))
    counts = rng.integers(0, 20, 40)
    values = rng.uniform(0, 1, (3, counts.sum()))
    got = segment_sums(values, counts)
    ends = np.cumsum(counts)
    for b, (lo, hi) in enumerate(zip(ends - counts, ends)):
        assert np.array_equal(got[:, b], values[:, lo:hi].sum(axis=1))
        assert np.array_equal(got[:, b], segment_sums(values[:, lo:hi], [hi - lo])[:, 0])
        assert all(got[r, b] == values[r, lo:hi].sum() for r in range(3))


def test_one_lookup_a_step_for_all_episodes(client):
    counting = Counting(client)
    env = SwarmAllocationVectorEnv(AllocConfig(**C5), num_envs=48, client=counting)  # many cells: pairs repeat
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    engaged_steps = deduplicated = 0
    for t in range(40):
        before = counting.calls
        _, _, _, _, infos = env.step(actions_for(env.action_space, rng, t))
        engaged = infos["engaged_cells"].sum() + infos.get("final_info", {}).get("engaged_cells", np.zeros(1)).sum()
        assert counting.calls - before == (1 if engaged else 0)
        if engaged:
            engaged_steps += 1
            assert len(counting.asked[-1]) <= engaged
            deduplicated += len(counting.asked[-1]) < engaged  # a pair met in several cells, asked once
    assert engaged_steps > 10 and env.engagements > engaged_steps and deduplicated > 0


@pytest.mark.parametrize("name", ["drift_5x5", "outnumbered_3x3"])
def test_make_vec_gives_the_batched_env_with_the_scenarios_settings(client, name):
    scenario = SCENARIOS[name]
    env = gymnasium.make_vec(scenario.gym_id, num_envs=3, vectorization_mode="vector_entry_point", client=client,
                             games=4, estimates="lattice")
    assert type(env) is SwarmAllocationVectorEnv and env.num_envs == 3
    assert env.config == scenario.config(games=4) and env.client is client and env.model.estimates == "lattice"
    assert env.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP and env.spec.id == scenario.gym_id
    n = scenario.env["grid_size"]
    assert env.observation_space.shape == (3, 2 * n * n) and env.single_action_space.shape == (farm.alloc.n_actions(n),)
    env.close()
    plain = gymnasium.make_vec(farm.alloc.ENV_ID, num_envs=2, client=client, **C3)  # the default mode: the entry point
    assert type(plain) is SwarmAllocationVectorEnv and plain.config == AllocConfig(**C3)


def test_same_step_autoreset_reports_the_ended_episode_and_starts_the_next(client):
    """'Stay' keeps the defenders at the base: the intruders are all through (breached or
    caught) at step 3 in every episode; the next episode starts in the same step."""
    cfg = AllocConfig(**C3)
    env = SwarmAllocationVectorEnv(cfg, num_envs=2, client=client)
    single = [SwarmAllocationEnv(cfg, client=client) for _ in range(2)]
    env.reset(seed=[4, 9])
    for s, seed in zip(single, (4, 9)):
        s.reset(seed=seed)
    stay = np.where(env.layout.src == env.layout.dst, 1.0, -1.0)
    for t in range(3):
        obs, _, term, trunc, infos = env.step(np.tile(stay, (2, 1)))
        steps = [s.step(stay) for s in single]
        if t < 2:
            assert "final_obs" not in infos and not (term | trunc).any()
    assert term.all() and not trunc.any()
    assert infos["_final_obs"].all() and infos["_final_info"].all()
    for k, s in enumerate(single):
        assert np.array_equal(infos["final_obs"][k], steps[k][0])
        assert all(infos["final_info"][key][k] == steps[k][4][key] for key, _ in INFO_KEYS)
        first, info = s.reset()
        assert np.array_equal(obs[k], first) and obs[k][cfg.grid_size] == 1.0  # all defenders at the base
        assert all(infos[key][k] == info[key] for key, _ in INFO_KEYS) and infos["breached"][k] == 0.0
    assert np.all(env.steps == 0) and np.all(env.breached == 0.0)


def test_get_state_and_set_state_continue_identically(client):
    cfg = AllocConfig(**DRIFT)
    env = SwarmAllocationVectorEnv(cfg, num_envs=4, client=client)
    env.reset(seed=21)
    rng = np.random.default_rng(2)
    for t in range(7):
        env.step(actions_for(env.action_space, rng, t))
    saved = pickle.loads(pickle.dumps(env.get_state()))
    actions = [actions_for(env.action_space, rng, t) for t in range(30)]
    first = [env.step(a) for a in actions]
    other = SwarmAllocationVectorEnv(cfg, num_envs=4, client=client)
    with pytest.raises(ResetNeeded):
        other.step(actions[0])
    other.set_state(saved)
    again = [other.step(a) for a in actions]
    for t, (x, y) in enumerate(zip(first, again)):
        for a, b in zip(x, y):
            assert_same(a, b, f"step {t}")
    assert (other.engagements, other.estimated) == (env.engagements, env.estimated)
    with pytest.raises(ConfigError, match="^set_state: "):
        SwarmAllocationVectorEnv(cfg, num_envs=3, client=client).set_state(saved)


@pytest.mark.parametrize("kw", [C3, SHORT], ids=["terminated", "truncated"])
def test_sb3_adapter_matches_dummy_vec_env_of_single_envs(client, kw):
    from stable_baselines3.common.vec_env import DummyVecEnv

    cfg = AllocConfig(**kw)
    ours = SB3VecEnv(SwarmAllocationVectorEnv(cfg, num_envs=3, client=client))
    ref = DummyVecEnv([lambda: SwarmAllocationEnv(cfg, client=client) for _ in range(3)])
    assert ours.seed(30) == ref.seed(30) == [30, 31, 32]
    assert np.array_equal(ours.reset(), ref.reset()) and ours.reset_infos == ref.reset_infos
    rng = np.random.default_rng(4)
    dones = 0
    for t in range(12):
        a = actions_for(ours.action_space, rng, t)[None].repeat(3, 0) * rng.uniform(0, 1, (3, 1))
        obs, rewards, done, infos = ours.step(a.astype(np.float32))
        r_obs, r_rewards, r_done, r_infos = ref.step(a.astype(np.float32))
        assert np.array_equal(obs, r_obs) and rewards.dtype == r_rewards.dtype == np.float32
        assert np.array_equal(rewards, r_rewards) and np.array_equal(done, r_done)
        for x, y in zip(infos, r_infos):
            assert set(x) == set(y)
            assert all(np.array_equal(x[key], y[key]) and type(x[key]) is type(y[key]) for key in x)
        assert ours.reset_infos == ref.reset_infos
        dones += done.sum()
    assert dones >= 6
    assert any(i["TimeLimit.truncated"] for i in infos) == (kw is SHORT)


def test_adapter_seeds_give_the_single_envs_first_observations(client):
    cfg = AllocConfig(**C5)
    vec = make_vec_env(cfg, 4, client, seed=100)
    obs = vec.reset()
    for k in range(4):
        assert np.array_equal(obs[k], SwarmAllocationEnv(cfg, client=client).reset(seed=100 + k)[0])
    vec.seed(7)
    assert np.array_equal(vec.reset()[2], SwarmAllocationEnv(cfg, client=client).reset(seed=9)[0])
    assert not np.array_equal(vec.reset()[2], SwarmAllocationEnv(cfg, client=client).reset(seed=9)[0])  # used once
    assert vec.get_attr("num_envs") == [4] * 4 and vec.env_is_wrapped(gymnasium.Wrapper) == [False] * 4
    state = vec.env_method("get_state")[0]
    assert state["D"].shape == (4, 25) and vec.venv.env.num_envs == 4
    with pytest.raises(ConfigError, match="^indices: "):
        vec.env_method("get_state", indices=[0])


@pytest.mark.parametrize("algorithm", ["PPO", "SAC", "TD3"])
def test_sb3_algorithms_learn_on_the_adapter_with_vec_monitor(client, algorithm):
    import stable_baselines3
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        vec = make_vec_env(AllocConfig(**C3), 4, client, seed=0)
        kwargs = ({"n_steps": 16, "batch_size": 32, "n_epochs": 1} if algorithm == "PPO"
                  else {"learning_starts": 40, "batch_size": 16, "buffer_size": 1000})
        model = getattr(stable_baselines3, algorithm)("MlpPolicy", vec, seed=0, device="cpu",
                                                      policy_kwargs={"net_arch": [16]}, **kwargs)
        model.learn(total_timesteps=256)
    finally:
        torch.set_num_threads(threads)
    assert model.num_timesteps >= 256 and len(model.ep_info_buffer) >= 20
    assert all(e["l"] >= 1 and np.isfinite(e["r"]) for e in model.ep_info_buffer)


@pytest.mark.parametrize("bad", [0, -2, 2.5, "4", True, None])
def test_num_envs_not_a_whole_number_is_one_config_error(bad):
    with pytest.raises(ConfigError) as err:
        SwarmAllocationVectorEnv(AllocConfig(**C3), num_envs=bad, client=object())
    message = str(err.value)
    assert message.startswith("num_envs: ") and len(message.splitlines()) == 1 and err.value.field == "num_envs"


def test_bad_actions_are_refused_before_anything_changes(client):
    counting = Counting(client)
    env = SwarmAllocationVectorEnv(AllocConfig(**C3), num_envs=2, client=counting)
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape))
    before, calls = env.get_state(), counting.calls
    A = env.single_action_space.shape[0]
    nan = np.zeros((2, A))
    nan[1, 3] = np.nan
    for bad in [np.zeros(A), np.zeros((3, A)), np.zeros((2, A + 1)), nan, np.full((2, A), "x"), "text"]:
        with pytest.raises(ActionError):
            env.step(bad)
    assert counting.calls == calls
    assert_same(env.get_state(), before)
    with pytest.raises(ConfigError, match="^render_mode: "):
        SwarmAllocationVectorEnv(AllocConfig(**C3), num_envs=2, client=client, render_mode="rgb_array")
    with pytest.raises(ConfigError, match="^seed: "):
        env.reset(seed=[1])
