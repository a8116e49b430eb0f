"""The intruders' env with its allocator's moves answered by helper processes (opponent_procs): the
same episodes, to the last bit, as one process answering them, for a planner, a mixture drawing
per episode and one drawing per step; the helpers stop with the env; bad procs are one line."""

import numpy as np
import pytest

from farm.alloc import SCENARIOS
from farm.alloc.intruder_env import SwarmIntruderVectorEnv
from farm.core.config import first_line
from farm.core.errors import ConfigError

OUT = SCENARIOS["outnumbered_3x3"]
GAMES = 4
MIXTURE = {"members": ["intercept", "receding_horizon", "spread_evenly"], "weights": [0.3, 0.5, 0.2]}


def _episodes(client, procs: int, opponent: str, options: dict, steps: int = 25) -> list:
    """Every step's observations, rewards and ends of 5 episodes (two autoresets deep) under a
    fixed sequence of pure routings."""
    env = SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=5, opponent=opponent, opponent_options=options,
                                 actions="pure", client=client, opponent_procs=procs)
    try:
        if procs > 1:
            assert len(env.opponent.helpers.actors) == min(procs, 2) - 1  # the node's 2 CPUs at most
        rng = np.random.default_rng(7)
        obs, _ = env.reset(seed=11)
        seen = [obs.tobytes()]
        for _ in range(steps):
            obs, r, term, trunc, _ = env.step(rng.integers(0, 2, size=env.action_space.shape))
            seen += [obs.tobytes(), r.tobytes(), term.tobytes(), trunc.tobytes()]
        saved = env.get_state()
        return seen + [repr(saved["moved"].tobytes())]
    finally:
        env.close()


@pytest.mark.ray
@pytest.mark.parametrize("opponent, options", [
    ("receding_horizon", {}),
    ("mixture", {**MIXTURE, "draw": "episode"}),
    ("mixture", {**MIXTURE, "draw": "step"}),
])
def test_helpers_answer_the_same_moves_as_one_process(ray_local, tmp_path, opponent, options):
    from farm.service.client import open_client

    with open_client(OUT.config(games=GAMES).game_settings(), mode="ray", store=tmp_path / "s.sqlite") as client:
        one = _episodes(client, 1, opponent, options)
        two = _episodes(client, 2, opponent, options)
        assert one == two
        assert _episodes(client, 3, opponent, options) == one  # capped at the node's CPUs


@pytest.mark.ray
def test_the_helpers_stop_with_the_env(ray_local, tmp_path):
    import ray

    from farm.service.client import open_client

    with open_client(OUT.config(games=GAMES).game_settings(), mode="ray", store=tmp_path / "s.sqlite") as client:
        env = SwarmIntruderVectorEnv(OUT.config(games=GAMES), num_envs=4, opponent="intercept", client=client,
                                     opponent_procs=2)
        (helper,) = env.opponent.helpers.actors
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
