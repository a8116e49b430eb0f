"""Checks come before the work and never write over results, in process (service.mode local),
no Ray.

- A pretraining expert's (or an intruders' opponent's) bad option is refused when the config is
  read, by the planner's own check, naming pretrain.expert_options: by `farm train` before any
  file is written, by train() itself, and by an experiment's plan (before Ray starts).
- `farm eval --references` with `none` beside a name, an empty entry or a name twice is refused;
  an evaluation that would write over one holding more policies is refused before any episode.
- An empty value of any flag is refused, one rule for `farm game --animate ''` and `farm eval
  --animate ''` (and --plot, --out, ...), never read as the flag left out.
- set_state with a damaged generator state is one line naming set_state, the env unchanged
  (the single env, the batched env, the intruders' envs).
"""

import copy

import numpy as np
import pandas as pd
import pytest

from farm.alloc import AllocConfig
from farm.core.errors import ConfigError

from conftest import farm_main, train_tiny_run
from helpers import farm_refusal

ENV = "env: {grid_size: 3, n_defenders: 10, n_intruders: 5, games: 3}\n"
TD3 = "td3: {n_timesteps: 200, learning_starts: 50}\n"


# ----- a bad expert option, refused when the config is read ----------------------------------------

@pytest.mark.parametrize("section, message", [
    ("pretrain: {expert: receding_horizon, expert_options: {horizon: 0}}",
     "pretrain.expert_options: horizon must be an integer >= 1, got 0"),
    ("pretrain: {expert: transport, expert_options: {horizon: 3}}",
     "pretrain.expert_options: transport has no option 'horizon' (options: power, min_count)"),
    ("pretrain: {expert: mmr, expert_options: {chunk: 50}}",
     "pretrain.expert_options: chunk 50 is more than the 10 defenders there are"),
    ("side: intruders\nopponent: {name: transport, options: {power: 0}}",
     "opponent.options: power must be a positive number, got 0"),
])
def test_farm_train_refuses_a_bad_expert_option_before_writing_anything(tmp_path, section, message):
    config = tmp_path / "t.yaml"
    config.write_text(f"name: t\n{ENV}{TD3}service: {{mode: local, store: {tmp_path / 's.sqlite'}}}\n{section}\n")
    status, out, err = farm_main("train", config, "--out", tmp_path / "run")
    farm_refusal(status, err, f"farm: error: {config}: {message}")
    assert not (tmp_path / "run").exists()


def test_train_refuses_a_bad_expert_option_before_writing_anything(tmp_path):
    from farm.alloc.training import TrainConfig, train

    config = TrainConfig(name="t", env={"grid_size": 3, "n_defenders": 10, "n_intruders": 5, "games": 3},
                         td3={"n_timesteps": 200, "learning_starts": 50},
                         pretrain={"expert": "receding_horizon", "expert_options": {"horizon": 0}},
                         service={"mode": "local", "store": str(tmp_path / "s.sqlite")})
    with pytest.raises(ConfigError) as e:
        train(config, tmp_path / "run", show_progress=False)
    assert str(e.value) == "pretrain.expert_options: horizon must be an integer >= 1, got 0"
    assert e.value.field == "pretrain.expert_options"
    assert not (tmp_path / "run").exists()


def test_an_experiment_refuses_a_bad_expert_option_of_a_point_before_ray_starts(tmp_path):
    from farm.studies.experiments.config import ExperimentConfig
    from farm.studies.experiments.plan import plan

    config = ExperimentConfig(name="e", base="configs/train/tiny.yaml", seeds=[0], store=str(tmp_path / "s.sqlite"),
                              overrides={"pretrain": {"expert": "receding_horizon"}},
                              grid={"pretrain.expert_options": [{"horizon": 2}, {"horizon": 0}]})
    with pytest.raises(ConfigError) as e:
        plan(config, "e.yaml")
    assert str(e.value).startswith("e.yaml: pretrain.expert_options: horizon must be an integer >= 1, got 0 "
                                   "(point 1: ")


# ----- farm eval: no contradiction, nothing written over -------------------------------------------

@pytest.mark.parametrize("references, message", [
    ("none,intercept", "--references: 'none' and 'intercept' contradict each other; give none alone, or the names"),
    ("intercept,,mmr", "--references: an empty entry in 'intercept,,mmr'"),
    ("intercept,intercept", "--references: 'intercept' is named twice"),
])
def test_farm_eval_refuses_contradictory_references(tmp_path, references, message):
    status, out, err = farm_main("eval", tmp_path / "nothere", "--references", references)
    farm_refusal(status, err, message)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return train_tiny_run(tmp_path_factory.mktemp("early"), "eval: {freq: 60, episodes: 2}\n")


def test_farm_eval_never_writes_over_an_evaluation_holding_more_policies(run):
    """The run's evaluation of every reference (a table standing in for it), then one of
    intercept alone: refused before any episode, the table as it was."""
    from farm.alloc.allocators import allocator_names

    table = pd.DataFrame({"policy": ["td3", *allocator_names(("baseline", "planner"), references=True)],
                          "return_mean": 0.0})
    table.to_csv(run / "eval_table.csv", index=False)
    before = (run / "eval_table.csv").read_bytes()
    status, out, err = farm_main("eval", run, "--episodes", 1, "--references", "intercept")
    farm_refusal(status, err, f"--references: {run / 'eval_table.csv'} holds the evaluation of stay_at_base, ",
                 "too, which this one would write over")
    assert (run / "eval_table.csv").read_bytes() == before
    assert not (run / "eval_episodes.csv").exists()


@pytest.mark.parametrize("command", [("game",), ("eval", "somewhere")])
def test_an_empty_animate_path_is_refused_by_one_rule(tmp_path, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    status, out, err = farm_main(*command, "--animate", "")
    farm_refusal(status, err, "--animate: an empty value; give one, or leave --animate out")
    assert out == "" and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, flag", [
    (("game", "--plot", ""), "--plot"),
    (("game", "--positions", " "), "--positions"),
    (("train", "nothere.yaml", "--out", ""), "--out"),
    (("eval", "nothere", "--references", ""), "--references"),
])
def test_an_empty_value_of_a_flag_is_refused_never_read_as_left_out(tmp_path, monkeypatch, argv, flag):
    monkeypatch.chdir(tmp_path)
    status, out, err = farm_main(*argv)
    farm_refusal(status, err, f"{flag}: an empty value")


# ----- set_state of a damaged generator state -------------------------------------------------------

def envs(tmp_path):
    from farm.alloc.envs.defenders import SwarmAllocationEnv
    from farm.alloc.envs.intruders import SwarmIntruderEnv, SwarmIntruderVectorEnv
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv

    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)
    store = str(tmp_path / "s.sqlite")
    return {"single": SwarmAllocationEnv(cfg, store=store), "batched": SwarmAllocationVectorEnv(cfg, 2, store=store),
            "intruders": SwarmIntruderEnv(cfg, store=store), "intruders batched": SwarmIntruderVectorEnv(cfg, 2,
                                                                                                      store=store)}


def damaged_generators(state: dict) -> list[dict]:
    """Copies of state with its generator state damaged in several ways."""
    key = "rng" if "rng" in state else "rngs"
    one = state[key] if key == "rng" else state[key][0]
    bad = [{**one, "state": None}, {**one, "bit_generator": "MT19937"}, {**one, "state": {"state": "x", "inc": 1}},
           "not a state"]
    out = []
    for b in bad:
        s = copy.deepcopy(state)
        if key == "rng":
            s[key] = b
        else:
            s[key][0] = b
        out.append(s)
    return out


@pytest.mark.parametrize("kind", ["single", "batched", "intruders", "intruders batched"])
def test_set_state_with_a_damaged_generator_state_is_one_line_the_env_unchanged(tmp_path, kind):
    env = envs(tmp_path)[kind]
    try:
        env.reset(seed=3)
        before = env.get_state()
        for bad in damaged_generators(before):
            with pytest.raises(ConfigError) as e:
                env.set_state(bad)
            assert str(e.value).startswith("set_state: the state's rng") and "\n" not in str(e.value)
            after = env.get_state()
            assert np.array_equal(after["D"], before["D"]) and after["steps"] is not None
            assert repr(after.get("rng", after.get("rngs"))) == repr(before.get("rng", before.get("rngs")))
    finally:
        env.close()
