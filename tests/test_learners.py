"""The learners (issue 25): `algo: td3 | ppo | sac`, planner-guided pretraining (DAgger) and
their exact resume, in process (`service.mode: local`), no Ray.

- Labels are the expert's actions on the states visited, whoever drove (checked against the
  expert called again on each state), and the mixture's share decides who drives.
- The fit brings each algorithm's actor close to the labels (its mean squared error falls by
  far), TD3's target actor following.
- Each algorithm trains into a run whose model.zip is that algorithm's, evaluated under its
  name by farm eval; PPO's run and a pretrained run resumed after a stop are bit-identical to
  uninterrupted ones.
- Bad `algo`, `pretrain` and `n_envs` settings are one line naming the field.
"""

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from farm.alloc import AllocConfig
from farm.alloc.allocators import make_allocator
from farm.alloc.training import TrainConfig, train
from farm.alloc.training.dagger import loop as pretrain_module
from farm.alloc.training.dagger.iterations import read_iteration
from farm.alloc.training.dagger.labels import play_labelled
from farm.alloc.training.dagger.loop import fit_actor, latest_iteration
from farm.service import CaptureTimeClient

from conftest import farm_main
from helpers import Stop, assert_same_policy, farm_refusal, stop_at

REPO = Path(__file__).resolve().parents[1]
SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3, team_sizes="lattice")


@pytest.fixture(scope="module")
def client(store):
    c = CaptureTimeClient(AllocConfig(**SMALL).game_settings(), local_store=store)
    yield c
    c.close()


def config(store, algo="td3", pretrain=None, **changes) -> TrainConfig:
    section = {"td3": {"n_timesteps": 300, "learning_starts": 100, "batch_size": 64, "buffer_size": 10000},
               "sac": {"n_timesteps": 300, "learning_starts": 100, "batch_size": 64, "buffer_size": 10000},
               "ppo": {"n_timesteps": 320, "n_steps": 64, "batch_size": 32, "n_epochs": 2}}[algo]
    raw = {"name": f"tiny-{algo}", "seed": 0, "env": SMALL, "algo": algo, algo: section,
           "eval": {"freq": 100, "episodes": 3}, "checkpoint_freq": 128,
           "service": {"mode": "local", "store": str(store)}}
    if pretrain is not None:
        raw["pretrain"] = pretrain
    raw.update(changes)
    return TrainConfig(**raw)


class Learner:
    """A fixed allocator that is not the expert: always the same action."""

    def __init__(self, n_actions: int):
        self.action = np.linspace(-1, 1, n_actions, dtype=np.float32)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.action.copy(), None


def test_labels_are_the_experts_actions_on_every_visited_state(client):
    env_config = AllocConfig(**SMALL)
    expert = make_allocator("intercept", env_config, client)
    learner = Learner(49)
    data = play_labelled(env_config, expert, learner, 0.5, [5, 6, 7], [1, 2], client, gamma=0.9)
    again = np.stack([expert.predict(o, deterministic=True)[0] for o in data["obs"]]).astype(np.float32)
    np.testing.assert_array_equal(data["labels"], again)
    by_learner = np.all(data["actions"] == learner.action, axis=1)
    by_expert = np.all(data["actions"] == data["labels"], axis=1)
    assert np.all(by_learner | by_expert) and by_learner.any() and by_expert.any()
    # the states follow one another: each next observation is the next state's, within an episode
    ends = data["terminated"] | data["truncated"]
    assert ends.sum() == 3
    np.testing.assert_array_equal(data["next_obs"][:-1][~ends[:-1]], data["obs"][1:][~ends[:-1]])
    # the returns are the discounted sums of the rewards to each episode's end
    last = np.flatnonzero(ends)
    first = np.concatenate([[0], last[:-1] + 1])
    for a, b in zip(first, last):
        r = data["rewards"][a: b + 1]
        assert data["returns"][a] == pytest.approx(sum(0.9 ** k * x for k, x in enumerate(r)))


def test_the_share_decides_who_drives(client):
    env_config = AllocConfig(**SMALL)
    expert, learner = make_allocator("intercept", env_config, client), Learner(49)
    alone = play_labelled(env_config, expert, learner, 1.0, [5, 6], [0], client, gamma=0.9)
    np.testing.assert_array_equal(alone["actions"], alone["labels"])
    never = play_labelled(env_config, expert, learner, 0.0, [5, 6], [0], client, gamma=0.9)
    assert np.all(never["actions"] == learner.action)
    same = play_labelled(env_config, expert, None, 0.0, [5, 6], [0], client, gamma=0.9)
    np.testing.assert_array_equal(same["actions"], alone["actions"])  # no learner: the expert drives


@pytest.mark.parametrize("algo", ["td3", "sac", "ppo"])
def test_the_fit_brings_the_actor_to_the_labels(store, client, algo):
    from farm.alloc.training.train import training_envs, make_model

    cfg = config(store, algo)
    env, _, _ = training_envs(cfg, client)
    model = make_model(cfg, env, Path("/nonexistent"))
    data = play_labelled(cfg.env, make_allocator("intercept", cfg.env, client), None, 1.0, list(range(20)), [0],
                         client, gamma=0.9)
    obs = torch.as_tensor(data["obs"])
    with torch.no_grad():
        before = float(((pretrain_module.actor_action(model, algo, obs) - torch.as_tensor(data["labels"])) ** 2).mean())
    loss = fit_actor(model, algo, data, epochs=150, batch_size=32, learning_rate=1e-3, rng=np.random.default_rng(0))
    with torch.no_grad():
        after = float(((pretrain_module.actor_action(model, algo, obs) - torch.as_tensor(data["labels"])) ** 2).mean())
    assert after < 0.2 * before and after < 0.05, (before, after, loss)
    predicted = np.stack([model.policy.predict(o, deterministic=True)[0] for o in data["obs"][:5]])
    assert np.abs(predicted - data["labels"][:5]).mean() < 0.1  # predict() acts on what was fitted
    if algo == "td3":
        for a, b in zip(model.actor.parameters(), model.actor_target.parameters()):
            assert torch.equal(a, b)


@pytest.mark.parametrize("algo", [pytest.param("td3", marks=pytest.mark.slow),
                                  pytest.param("sac", marks=pytest.mark.slow), "ppo"])
def test_each_algorithm_trains_a_model_of_its_own_kind(store, tmp_path, algo):
    import stable_baselines3

    from farm.alloc.evaluation.evaluate import evaluate_run

    metrics = train(config(store, algo), tmp_path / "run", show_progress=False)
    assert metrics["algo"] == algo and metrics["timesteps"] >= 300
    getattr(stable_baselines3, algo.upper()).load(tmp_path / "run" / "model.zip", device="cpu")
    result = evaluate_run(tmp_path / "run", episodes=2)
    assert result.table["policy"].iloc[0] == algo


def test_a_ppo_run_resumed_after_a_stop_is_bit_identical(store, tmp_path):
    cfg = config(store, "ppo")
    train(cfg, tmp_path / "whole", show_progress=False)
    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False, callbacks=[stop_at(200)])
    train(cfg, tmp_path / "stopped", resume=True, show_progress=False)
    assert_same_policy(tmp_path / "whole" / "model.zip", tmp_path / "stopped" / "model.zip", "ppo")
    with np.load(tmp_path / "whole" / "evaluations.npz") as a, np.load(tmp_path / "stopped" / "evaluations.npz") as b:
        np.testing.assert_array_equal(a["results"], b["results"])
        np.testing.assert_array_equal(a["timesteps"], b["timesteps"])


PRETRAIN = {"expert": "intercept", "iterations": 3, "episodes": 4, "expert_share": 0.5, "epochs": 5,
            "batch_size": 16, "episodes_per_task": 2}


@pytest.mark.parametrize("algo", [pytest.param("td3", marks=pytest.mark.slow), "ppo"])
def test_a_pretrain_resumed_after_a_stop_is_bit_identical(store, tmp_path, monkeypatch, algo):
    cfg = config(store, algo, pretrain=PRETRAIN, keep="best")
    whole = train(cfg, tmp_path / "whole", show_progress=False)
    assert whole["pretrain_states"] > 0 and whole["pretrained_eval_mean_return"] is not None
    real, calls = pretrain_module.label_all, []

    def stop_in_iteration_2(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise Stop()
        return real(*args, **kwargs)

    monkeypatch.setattr(pretrain_module, "label_all", stop_in_iteration_2)
    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False)
    assert latest_iteration(tmp_path / "stopped") == 0
    monkeypatch.setattr(pretrain_module, "label_all", real)
    resumed = train(cfg, tmp_path / "stopped", resume=True, show_progress=False)
    for k in range(PRETRAIN["iterations"]):
        a = read_iteration(pretrain_module.iteration_file(tmp_path / "whole", k))
        b = read_iteration(pretrain_module.iteration_file(tmp_path / "stopped", k))
        for name in a["data"]:
            np.testing.assert_array_equal(a["data"][name], b["data"][name])
        assert all(torch.equal(a["policy"][p], b["policy"][p]) for p in a["policy"])
    assert_same_policy(tmp_path / "whole" / "model.zip", tmp_path / "stopped" / "model.zip", algo)
    assert resumed["pretrain_states"] == whole["pretrain_states"]
    assert resumed["pretrained_eval_mean_return"] == whole["pretrained_eval_mean_return"]
    assert (whole["pretrain_resumed_after"], resumed["pretrain_resumed_after"]) == (None, 0)


def test_the_pretrained_model_is_evaluated_first_and_kept_when_best(store, tmp_path):
    cfg = config(store, "ppo", pretrain=PRETRAIN, keep="best")
    told = []
    metrics = train(cfg, tmp_path / "run", show_progress=False, on_pretrain=lambda *a: told.append(a))
    total = PRETRAIN["iterations"] * PRETRAIN["episodes"]  # one map: a report labelled, a report fitted
    assert told == [(k * PRETRAIN["episodes"], total, saved) for k in range(1, PRETRAIN["iterations"] + 1)
                    for saved in (None, k - 1)]
    with np.load(tmp_path / "run" / "evaluations.npz") as e:
        assert e["timesteps"][0] == 0
        means = e["results"].mean(axis=1)
    assert metrics["pretrained_eval_mean_return"] == pytest.approx(means[0])
    assert metrics["kept"] == ("final" if means[-1] >= means.max() else "best")


@pytest.mark.parametrize("changes, field", [
    ({"algo": "a2c"}, "algo"),
    ({"n_envs": 0}, "n_envs"),
    ({"n_envs": 2.5}, "n_envs"),
    ({"pretrain": {"expert": "oracle"}}, "pretrain.expert"),
    ({"pretrain": {"expert": "ppo"}}, "pretrain.expert"),
    ({"pretrain": {"iterations": 0}}, "pretrain.iterations"),
    ({"pretrain": {"iterations": 2, "expert_share": [1.0]}}, "pretrain"),
    ({"pretrain": {"expert_share": 1.5}}, "pretrain.expert_share"),
    ({"pretrain": {"schedule": 3}}, "pretrain.schedule"),
    ({"ppo": {"n_steps": 64}}, "ppo"),
    ({"algo": "ppo", "ppo": {"batch_size": 1}}, "ppo.batch_size"),
    ({"algo": "sac", "sac": {"ent_coef": -1.0}}, "sac.ent_coef"),
    ({"algo": "ppo", "ppo": {"policy_kwargs": {"n_critics": 2}}}, "ppo.policy_kwargs"),
])
def test_a_bad_learner_setting_is_one_line_naming_the_field(tmp_path, changes, field):
    raw = yaml.safe_load((REPO / "configs" / "train" / "tiny.yaml").read_text())
    raw.update(changes)
    assert_refused_in_one_line(tmp_path, raw, field)


def assert_refused_in_one_line(tmp_path: Path, raw: dict, field: str) -> None:
    """`farm train` of the training config raw (farm.cli.main in this process): one line on stderr
    naming field, no run folder."""
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    status, _, stderr = farm_main("train", path, "--out", tmp_path / "run")  # in process: the CLI's own
    farm_refusal(status, stderr, field)  # process is test_alloc_train's
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("action_map", ["softmax", "shifted"])
def test_the_flows_loss_reads_actions_as_the_env_does(action_map, tmp_path):
    from farm.alloc import SwarmAllocationEnv
    from farm.alloc.training.dagger.loop import MoveMap

    cfg = AllocConfig(grid_size=4, n_defenders=10, n_intruders=5, action_map=action_map)
    env = SwarmAllocationEnv(cfg, store=tmp_path / "s.sqlite")
    actions = np.random.default_rng(0).uniform(-1.5, 1.5, (5, env.action_space.shape[0]))
    ours = MoveMap(cfg).log_probabilities(torch.as_tensor(actions)).exp().numpy()
    theirs = np.stack([env.move_probabilities(a) for a in actions])
    np.testing.assert_allclose(ours, theirs, atol=1e-15 if action_map == "softmax" else 1e-5)
    env.close()


def test_the_flows_fit_moves_the_defenders_as_the_expert_does(store, client):
    from farm.alloc.training.dagger.loop import MoveMap
    from farm.alloc.training.train import training_envs, make_model

    cfg = config(store, "ppo")
    env, _, _ = training_envs(cfg, client)
    model = make_model(cfg, env, Path("/nonexistent"))
    data = play_labelled(cfg.env, make_allocator("intercept", cfg.env, client), None, 1.0, list(range(20)), [0],
                         client, gamma=0.9)
    moves = MoveMap(cfg.env)

    def misdirected() -> float:  # the share of the defenders the learner sends elsewhere than the expert
        with torch.no_grad():
            ours = moves.log_probabilities(pretrain_module.actor_action(model, "ppo", torch.as_tensor(data["obs"])))
            theirs = moves.log_probabilities(torch.as_tensor(data["labels"]))
        D = torch.as_tensor(data["obs"][:, :9])[:, moves.src]
        return float(((D * (ours.exp() - theirs.exp()).abs()).sum(dim=1) / 2).mean())

    before = misdirected()
    fit_actor(model, "ppo", data, epochs=100, batch_size=32, learning_rate=1e-3, rng=np.random.default_rng(0),
              loss="flows", env_config=cfg.env)
    after = misdirected()
    assert after < 0.2 * before and after < 0.1, (before, after)


@pytest.mark.parametrize("algo, repair", [("ppo", "none"), ("sac", "none"), ("ppo", "levels")])
def test_a_run_on_the_batched_env_resumed_after_a_stop_is_bit_identical(store, tmp_path, algo, repair):
    # repair levels: the periodic evaluations act through the level repair (test_repair)
    cfg = config(store, algo, n_envs=4, repair=repair, keep="best" if repair == "levels" else "final")
    metrics = train(cfg, tmp_path / "whole", show_progress=False)
    assert metrics["timesteps"] >= 300
    with np.load(tmp_path / "whole" / "evaluations.npz") as e:  # every eval.freq steps, as with one env
        assert list(e["timesteps"]) == list(range(100, metrics["timesteps"] + 1, 100))
    with pytest.raises(Stop):
        train(cfg, tmp_path / "stopped", show_progress=False, callbacks=[stop_at(200)])
    train(cfg, tmp_path / "stopped", resume=True, show_progress=False)
    assert_same_policy(tmp_path / "whole" / "model.zip", tmp_path / "stopped" / "model.zip", algo)
    with np.load(tmp_path / "whole" / "evaluations.npz") as a, np.load(tmp_path / "stopped" / "evaluations.npz") as b:
        np.testing.assert_array_equal(a["results"], b["results"])
