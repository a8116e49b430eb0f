"""The intruders' env with its allocator's moves answered by helper processes (opponent_procs): the
same episodes, to the last bit, as one process answering them, for a planner, a mixture drawing
per episode and one drawing per step; the helpers stop with the env, and with a training that fails
before its steps; bad procs are one line."""

import numpy as np
import pytest

from farm.alloc import SCENARIOS
from farm.alloc.envs.intruders import SwarmIntruderVectorEnv
from farm.core.config import first_line
from farm.core.errors import ConfigError

OUT = SCENARIOS["outnumbered_3x3"]
GAMES = 4
MIXTURE = {"members": ["intercept", "receding_horizon", "spread_evenly"], "weights": [0.3, 0.5, 0.2]}


@pytest.fixture(scope="module")
def client(ray_local, tmp_path_factory):
    """One client on the capture-time service actor for the module (its store filled once)."""
    from farm.service.client import open_client

    with open_client(OUT.config(games=GAMES).game_settings(), mode="ray",
                     store=tmp_path_factory.mktemp("store") / "s.sqlite") as client:
        yield client


def _episodes(client, procs: int, options: dict, steps: int = 15) -> list:
    """Every step's observations, rewards and ends of 5 episodes (autoresets among them) against
    a mixture with options, under a fixed sequence of pure routings."""
    env = SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=5, opponent="mixture", opponent_options=options,
                                 actions="pure", client=client, opponent_procs=procs)
    try:
        rng = np.random.default_rng(7)
        obs, _ = env.reset(seed=11)
        seen = [obs.tobytes()]
        for _ in range(steps):
            obs, r, term, trunc, _ = env.step(rng.integers(0, 2, size=env.action_space.shape))
            seen += [obs.tobytes(), r.tobytes(), term.tobytes(), trunc.tobytes()]
        return seen + [env.get_state()["moved"].tobytes()]
    finally:
        env.close()


@pytest.mark.ray
@pytest.mark.parametrize("draw", ["episode", "step"])
def test_helpers_answer_the_same_moves_as_one_process(client, draw):
    options = {**MIXTURE, "draw": draw}
    assert _episodes(client, 2, options) == _episodes(client, 1, options)


@pytest.mark.ray
def test_the_helpers_are_at_most_the_nodes_cpus_and_stop_with_the_env(client):
    import ray

    env = SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=4, opponent="intercept", client=client,
                                 opponent_procs=3)
    (helper,) = env.opponent.helpers.actors  # the node's 2 CPUs: the env's process and one helper
    env.close()
    with pytest.raises(ray.exceptions.RayActorError):
        ray.get(helper.predict.remote([()], np.zeros((1, 18), np.float32)), timeout=60)


@pytest.mark.parametrize("procs", [0, 1.5, "two", True])
def test_bad_opponent_procs_is_one_line(procs, tmp_path):
    with pytest.raises(ConfigError) as e:
        SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=2, opponent="intercept", opponent_procs=procs,
                               store=str(tmp_path / "s.sqlite"))
    assert first_line(str(e.value)).startswith("opponent_procs: must be a whole number >= 1")


def test_helpers_need_the_service_on_ray(tmp_path):
    with pytest.raises(ConfigError, match="^opponent_procs: helpers need Ray"):
        SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=2, opponent="intercept", opponent_procs=2,
                               store=str(tmp_path / "s.sqlite"))


def test_train_and_an_experiment_refuse_bad_opponent_procs_before_anything_is_written(tmp_path):
    from farm.alloc.training import TrainConfig, train
    from farm.studies.experiments.config import ExperimentConfig
    from farm.studies.experiments.run import run_experiment

    with pytest.raises(ConfigError, match="^opponent_procs: must be a whole number >= 1, got 0$"):
        train(TrainConfig(name="t"), tmp_path / "run", opponent_procs=0)
    experiment = ExperimentConfig(name="e", base="configs/train/tiny.yaml", seeds=[0], store=str(tmp_path / "s.sqlite"))
    with pytest.raises(ConfigError, match="^opponent_procs: must be a whole number >= 1, got 'two'$"):
        run_experiment(experiment, tmp_path / "exp", opponent_procs="two")
    assert not any(tmp_path.iterdir())


@pytest.mark.ray
def test_a_training_that_fails_before_its_steps_stops_its_helpers(client, tmp_path, monkeypatch):
    import importlib

    import ray

    from farm.alloc.training import TrainConfig

    train_module = importlib.import_module("farm.alloc.training.train")

    made = []
    original = train_module.training_envs

    def kept(*args, **kwargs):
        envs = original(*args, **kwargs)
        made.extend(envs[1].opponent.helpers.actors)
        return envs

    def broken(*args, **kwargs):
        raise RuntimeError("the model cannot be made")

    monkeypatch.setattr(train_module, "training_envs", kept)
    monkeypatch.setattr(train_module, "make_model", broken)
    config = TrainConfig(name="helpers", seed=0, scenario="outnumbered_3x3", env={"games": GAMES}, side="intruders",
                         opponent={"name": "intercept"}, n_envs=2, eval={"freq": 100, "episodes": 1})
    with pytest.raises(RuntimeError, match="cannot be made"):
        train_module._start(config, tmp_path, False, False, client, None, None, opponent_procs=2)
    (helper,) = made  # the node's 2 CPUs: the env's process and one helper
    with pytest.raises(ray.exceptions.RayActorError):
        ray.get(helper.predict.remote([()], np.zeros((1, 18), np.float32)), timeout=60)
