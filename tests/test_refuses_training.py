"""Issue 17, training, the env and trained models: bad input never becomes a wrong result.

A run that diverges (a loss, a parameter or an action not finite) stops with
TrainingDiverged naming the step and writes no model.zip or metrics.json; the guard changes
nothing in a run that does not diverge. The env refuses a NaN or infinite action and one
of another shape (ActionError, a workers.InputError) before it changes anything, and steps
every valid action as before (values outside [-1, 1] clipped). `farm eval` on a truncated
or damaged model.zip is one line naming the file.

Property test (hypothesis): SwarmAllocationEnv.step with arbitrary arrays (shapes, dtypes,
NaN, infinities), lists and other objects either steps or raises ActionError.
Example count: 300 (about 10 s).
"""

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from helpers import farm_process as farm
from hypothesis.extra import numpy as hnp
from stable_baselines3 import TD3
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.allocators.learned import load_model
from farm.alloc.training import DivergenceGuard, TrainConfig, train
from farm.core.errors import ActionError, ModelError, TrainingDiverged
from workers import InputError

REPO = Path(__file__).resolve().parents[1]
SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)
TINY = dict(grid_size=3, n_defenders=4, n_intruders=2, games=2)


def tiny_run(store, **td3):
    """A 60-step run on a small grid (net 32-32), its td3 settings changed by td3."""
    return TrainConfig(name="tiny", env=AllocConfig(**SMALL), threads=1,
                       td3={"n_timesteps": 60, "learning_starts": 20, "batch_size": 16,
                            "policy_kwargs": {"net_arch": [32, 32]}, **td3},
                       eval={"freq": 30, "episodes": 1}, checkpoint_freq=60,
                       service={"mode": "local", "store": str(store)})


def assert_not_a_run(run):
    assert not (run / "metrics.json").exists() and not (run / "model.zip").exists()
    assert (run / "DIVERGED").read_text().startswith("training diverged at step ")  # farm report says so


# ----- 4. training stops on divergence --------------------------------------------------

def test_a_huge_learning_rate_stops_training_naming_the_step(store, tmp_path):
    """learning_rate 1e30 (finite): every policy tensor became NaN and metrics.json still
    reported a normal-looking return."""
    run = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match=r"^training diverged at step \d+: ") as err:
        train(tiny_run(store, learning_rate=1e30), run, show_progress=False)
    step = int(str(err.value).split("step ")[1].split(":")[0])
    assert 20 < step <= 60 and len(str(err.value).splitlines()) == 1
    assert_not_a_run(run)


def test_a_parameter_that_turns_nan_stops_training_at_that_step(store, tmp_path, monkeypatch):
    original = TD3.train

    def poisoned(self, *args, **kwargs):
        original(self, *args, **kwargs)
        if self.num_timesteps == 30:
            with torch.no_grad():
                self.actor.mu[0].weight[0, 0] = float("nan")

    monkeypatch.setattr(TD3, "train", poisoned)
    run = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match=r"^training diverged at step 30: the policy's actor\.mu\.0\.weight "
                                               r"is not finite after the update"):
        train(tiny_run(store), run, show_progress=False)
    assert_not_a_run(run)


def test_a_nan_loss_stops_training_at_that_step(store, tmp_path, monkeypatch):
    original = TD3.train

    def logged_nan(self, *args, **kwargs):
        original(self, *args, **kwargs)
        if self.num_timesteps == 25:
            self.logger.record("train/critic_loss", float("nan"))

    monkeypatch.setattr(TD3, "train", logged_nan)
    with pytest.raises(TrainingDiverged, match=r"^training diverged at step 25: train/critic_loss is nan"):
        train(tiny_run(store), tmp_path / "run", show_progress=False)
    assert_not_a_run(tmp_path / "run")


def test_a_nan_action_stops_training_at_that_step(store, tmp_path, monkeypatch):
    """The policy's first own action (after learning_starts = 20 random ones) is NaN: the env
    refuses it and the run stops at step 21."""
    from stable_baselines3.td3.policies import Actor

    original = Actor.forward
    monkeypatch.setattr(Actor, "forward", lambda self, obs: original(self, obs) * float("nan"))
    with pytest.raises(TrainingDiverged, match=r"^training diverged at step 21: the policy's action is not finite"):
        train(tiny_run(store), tmp_path / "run", show_progress=False)
    assert_not_a_run(tmp_path / "run")


@pytest.mark.slow
def test_the_cli_reports_a_diverged_run_in_one_line(store, tmp_path):
    config = tmp_path / "diverges.yaml"
    config.write_text(yaml.safe_dump(json.loads(tiny_run(store, learning_rate=1e30).model_dump_json())))
    r = farm("train", config, "--out", tmp_path / "run", "--quiet")
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.startswith("farm: error: training diverged at step ") and len(r.stderr.strip().splitlines()) == 1
    assert_not_a_run(tmp_path / "run")


def test_the_guard_changes_nothing_in_a_run_that_does_not_diverge(store):
    """Parameters after 80 steps bit for bit the same with and without DivergenceGuard."""
    def trained(callback):
        env = DummyVecEnv([lambda: Monitor(SwarmAllocationEnv(AllocConfig(**SMALL), store=str(store)))])
        model = TD3("MlpPolicy", env, policy_kwargs={"net_arch": [32, 32]}, learning_starts=30, batch_size=16,
                    seed=5, device="cpu")
        model.learn(80, callback=callback)
        return [p.detach().clone() for p in model.policy.parameters()]

    with_guard, without = trained(DivergenceGuard()), trained(None)
    assert all(torch.equal(a, b) for a, b in zip(with_guard, without))


# ----- 5. the env checks its action -------------------------------------------------------

@pytest.fixture(scope="module")
def env(tmp_path_factory):
    env = SwarmAllocationEnv(AllocConfig(**TINY), store=tmp_path_factory.mktemp("env") / "store.sqlite")
    yield env
    env.close()


def state(env):
    return env.D.copy(), env.I.copy(), env.steps, env.breached, env.eliminated


def same_state(a, b):
    return all(np.array_equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_action_is_refused_and_changes_nothing(env, bad):
    """A NaN action turned the observation NaN for the rest of the episode while the
    reward stayed finite."""
    env.reset(seed=0)
    before = state(env)
    action = np.zeros(49, np.float32)
    action[7] = bad
    with pytest.raises(ActionError, match=r"^action: expected shape \(49,\) of finite numbers in the action "
                                          r"space, got (nan|inf|-inf) at index 7") as err:
        env.step(action)
    assert isinstance(err.value, InputError) and isinstance(err.value, ValueError)
    assert same_state(state(env), before)
    obs, reward, *_ = env.step(np.zeros(49))  # the episode goes on as if nothing had been asked
    assert np.isfinite(obs).all() and np.isfinite(reward)


@pytest.mark.parametrize("shape", [(3,), (48,), (50,), (1, 49), (), (49, 1)])
def test_an_action_of_another_shape_is_one_clear_error(env, shape):
    """Shape (3,) was an IndexError deep in numpy."""
    env.reset(seed=0)
    with pytest.raises(ActionError) as err:
        env.step(np.zeros(shape))
    assert str(err.value) == f"action: expected shape (49,) of finite numbers in the action space, got shape {shape}"


@pytest.mark.parametrize("action", [np.zeros(49, bool), np.zeros(49, complex), ["a"] * 49, None, [[0.0] * 3, [0.0]],
                                    {"a": 1}])
def test_an_action_that_is_not_real_numbers_is_refused(env, action):
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"^action: expected shape \(49,\) of finite numbers"):
        env.step(action)


def test_valid_actions_step_exactly_as_before_values_outside_the_box_clipped(tmp_path):
    """A valid action of any real dtype, in or outside [-1, 1], steps exactly like its float64
    values clipped to [-1, 1] (what step() did before the check)."""
    rng = np.random.default_rng(3)
    store = tmp_path / "s.sqlite"
    a, b = (SwarmAllocationEnv(AllocConfig(**TINY), store=store) for _ in range(2))
    a.reset(seed=4)
    b.reset(seed=4)
    for k in range(6):
        raw = rng.normal(scale=3.0, size=49)
        action = [raw.astype(np.float32), raw, raw.tolist(), np.rint(raw).astype(np.int64)][k % 4]
        clipped = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        out_a, out_b = a.step(action), b.step(clipped)
        np.testing.assert_array_equal(out_a[0], out_b[0])
        assert out_a[1:] == out_b[1:]
    a.close()
    b.close()


DTYPES = [np.float16, np.float32, np.float64, np.longdouble, np.int8, np.int64, np.uint8, np.uint64, np.bool_,
          np.complex64]
actions = st.one_of(
    hnp.arrays(st.sampled_from(DTYPES), st.just((49,))),
    hnp.arrays(np.float32, st.just((49,)), elements=st.floats(-3, 3, width=32)),
    hnp.arrays(st.sampled_from(DTYPES), hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=60)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True) | st.integers(-5, 5), min_size=47, max_size=51),
    st.none(), st.text(max_size=3), st.booleans(), st.floats())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(actions)
def test_property_step_either_steps_or_raises_the_projects_error(env, action):
    env.reset(seed=0)
    before = state(env)
    try:
        obs, reward, terminated, truncated, info = env.step(action)
    except ActionError as e:
        assert str(e).startswith("action: expected shape (49,) of finite numbers in the action space, got ")
        assert same_state(state(env), before)
        return
    assert obs.shape == (18,) and obs.dtype == np.float32 and np.isfinite(obs).all()
    assert 0 <= obs.min() and obs.max() <= 1 and np.isfinite(reward)
    assert np.isclose(env.D.sum(), 1.0) and env.steps == 1


# ----- 6. a damaged model.zip -------------------------------------------------------------

@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A run folder with an (untrained) model.zip and its config.yaml; no game is played."""
    run = tmp_path_factory.mktemp("model") / "run"
    run.mkdir()
    config = TrainConfig(name="m", env=AllocConfig(**SMALL), service={"mode": "local", "store": str(run / "s.sqlite")})
    (run / "config.yaml").write_text(yaml.safe_dump(json.loads(config.model_dump_json())))
    env = DummyVecEnv([lambda: SwarmAllocationEnv(AllocConfig(**SMALL), client=object())])
    TD3("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=0, device="cpu").save(run / "model.zip")
    return run


def damaged(run_folder, tmp_path, how):
    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    path = run / "model.zip"
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "text":
        path.write_text("not a model\n")
    elif how == "member":  # a sound zip whose policy is garbage
        with zipfile.ZipFile(run_folder / "model.zip") as src, zipfile.ZipFile(path, "w") as out:
            for item in src.infolist():
                out.writestr(item, b"garbage" if item.filename == "policy.pth" else src.read(item))
    elif how == "no data":
        with zipfile.ZipFile(run_folder / "model.zip") as src, zipfile.ZipFile(path, "w") as out:
            for item in src.infolist():
                if item.filename != "data":
                    out.writestr(item, src.read(item))
    return run


def test_a_sound_model_loads(run_folder):
    assert load_model(run_folder).policy is not None


@pytest.mark.parametrize("how", ["truncated", "empty", "text", "member", "no data"])
def test_a_damaged_model_zip_is_one_error_naming_the_file(run_folder, tmp_path, how):
    run = damaged(run_folder, tmp_path, how)
    with pytest.raises(ModelError) as err:
        load_model(run)
    message = str(err.value)
    assert message.startswith(f"{run / 'model.zip'}: not a loadable stable-baselines3 TD3 model (")
    assert len(message.splitlines()) == 1


def test_a_model_with_nan_parameters_is_refused(run_folder, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    model = TD3.load(run / "model.zip", device="cpu")
    with torch.no_grad():
        next(model.policy.parameters()).fill_(float("nan"))
    model.save(run / "model.zip")
    with pytest.raises(ModelError, match=r"model\.zip: the policy's .* is not finite"):
        load_model(run)


@pytest.mark.slow
def test_farm_eval_of_a_truncated_model_is_one_line(run_folder, tmp_path):
    run = damaged(run_folder, tmp_path, "truncated")
    r = farm("eval", run, "--episodes", 1)
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.startswith(f"farm: error: {run / 'model.zip'}: not a loadable stable-baselines3 TD3 model (")
    assert len(r.stderr.strip().splitlines()) == 1
