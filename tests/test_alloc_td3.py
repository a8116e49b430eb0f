"""AllocTD3 and LeanVecEnv: SB3's TD3 and DummyVecEnv with a lean per-step path, checked
against the stock classes."""

import numpy as np
import pytest
import torch
from stable_baselines3 import TD3
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.env import LATTICE, snap, snap_many
from farm.alloc.td3 import AllocTD3, LeanVecEnv, _mode_free

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, c_capture=1.5)
NET = {"net_arch": [400, 300]}


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    return str(tmp_path_factory.mktemp("td3") / "store.sqlite")


def make(store):
    return SwarmAllocationEnv(AllocConfig(**SMALL), store=store)


def test_snap_is_the_nearest_lattice_size_in_log_scale():
    import math

    x = np.arange(1, 5001)
    slow = [min(LATTICE, key=lambda v: (abs(math.log(v) - math.log(int(n))), v)) for n in x]
    assert snap_many(x).tolist() == slow
    assert [snap(int(n)) for n in x[:300]] == slow[:300]
    assert snap(100_000) == 256 and set(snap_many(x).tolist()) == set(LATTICE)


def test_mode_free_detects_mode_dependent_layers(store):
    model = AllocTD3("MlpPolicy", make(store), policy_kwargs=NET, device="cpu")
    assert _mode_free(model.policy)
    assert not _mode_free(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.Dropout(0.1)))
    assert not _mode_free(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.BatchNorm1d(2)))
    assert not _mode_free(torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.GELU()))


def test_numpy_actor_tracks_the_torch_actor(store, tmp_path, rng):
    """The numpy forward reads the parameters the optimizer and the soft update change
    in place: it equals the torch actor before training, after training, after load."""
    model = AllocTD3("MlpPolicy", make(store), policy_kwargs=NET, learning_starts=50, batch_size=32, seed=0,
                     device="cpu")
    obs = rng.uniform(0, 1, (7, 18)).astype(np.float32)

    def agree(m):
        with torch.no_grad():
            expected = m.actor(torch.as_tensor(obs)).numpy()
        assert np.abs(m._actor_forward(obs) - expected).max() < 1e-5

    agree(model)
    before = model._actor_forward(obs)
    model.learn(120)
    assert np.abs(model._actor_forward(obs) - before).max() > 1e-4, "the actor did not train"
    agree(model)
    assert 0 < model.update_seconds
    model.save(tmp_path / "m.zip")
    loaded = AllocTD3.load(tmp_path / "m.zip", device="cpu")
    agree(loaded)
    np.testing.assert_allclose(loaded._actor_forward(obs), model._actor_forward(obs), atol=1e-6)
    vector = model.policy.parameters_to_vector()
    model.policy.load_from_vector(vector * 0.5)  # replaces the parameters' storage: the views follow
    agree(model)
    plain = TD3.load(tmp_path / "m.zip", device="cpu")  # the saved model is plain SB3
    np.testing.assert_allclose(plain.predict(obs, deterministic=True)[0], loaded._actor_forward(obs), atol=1e-5)


def test_same_transitions_as_stock_td3(store):
    """Same seed: AllocTD3 (numpy actor, no mode switches, LeanVecEnv) and SB3's TD3 (predict,
    DummyVecEnv) store the same transitions, up to float32 rounding of the actions."""
    buffers = []
    for cls, vec in ((TD3, DummyVecEnv), (AllocTD3, LeanVecEnv)):
        env = vec([lambda: Monitor(make(store))])
        model = cls("MlpPolicy", env, policy_kwargs=NET, learning_starts=60, batch_size=32, seed=3, device="cpu")
        model.learn(160)
        buffers.append(model.replay_buffer)
    a, b = buffers
    assert a.pos == b.pos == 160
    np.testing.assert_allclose(a.actions[:160], b.actions[:160], atol=1e-4)
    np.testing.assert_allclose(a.observations[:160], b.observations[:160], atol=1e-4)
    np.testing.assert_allclose(a.next_observations[:160], b.next_observations[:160], atol=1e-4)
    np.testing.assert_allclose(a.rewards[:160], b.rewards[:160], atol=1e-4)
    np.testing.assert_array_equal(a.dones[:160], b.dones[:160])
    np.testing.assert_array_equal(a.timeouts[:160], b.timeouts[:160])


def test_lean_vec_env_steps_like_dummy_vec_env(store, rng):
    envs = [vec([lambda: Monitor(make(store))]) for vec in (DummyVecEnv, LeanVecEnv)]
    for e in envs:
        e.seed(11)
    first = [e.reset() for e in envs]
    np.testing.assert_array_equal(*first)
    episodes = 0
    for _ in range(40):
        action = rng.uniform(-1, 1, (1, 49)).astype(np.float32)
        (o1, r1, d1, i1), (o2, r2, d2, i2) = (e.step(action.copy()) for e in envs)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        assert i1[0].keys() == i2[0].keys()
        for k in i1[0]:
            if k == "episode":
                assert i1[0][k]["r"] == i2[0][k]["r"] and i1[0][k]["l"] == i2[0][k]["l"]
            else:
                np.testing.assert_array_equal(i1[0][k], i2[0][k])
        episodes += int(d1[0])
    assert episodes >= 3
    with pytest.raises(ValueError, match="only Box observation spaces"):
        import gymnasium

        class DictEnv(gymnasium.Env):
            observation_space = gymnasium.spaces.Dict({"x": gymnasium.spaces.Box(0, 1, (1,))})
            action_space = gymnasium.spaces.Box(-1, 1, (1,))

        LeanVecEnv([DictEnv])
