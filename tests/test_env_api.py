"""SwarmAllocationEnv as gymnasium's users expect it, without gym.make's wrappers: step
before reset, a config with keyword arguments, close() and the store, attributes made in
__init__. Fast: no game is computed and no Ray is started."""

import sqlite3

import gymnasium
import numpy as np
import pytest
from gymnasium.error import ResetNeeded

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.core.errors import ConfigError
from farm.service import CaptureTimeClient, StatsStore

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)


def stay(env):
    """Every cell keeps its defenders: after reset, no cell holds both sides, so no game."""
    return np.where(env.src == env.dst, 1.0, -1.0).astype(np.float32)


def test_step_before_reset_is_an_error():
    env = SwarmAllocationEnv(AllocConfig(**SMALL), client=object())
    with pytest.raises(ResetNeeded, match=r"Cannot call env\.step\(\) before calling env\.reset\(\)"):
        env.step(stay(env))
    assert env.steps == 0 and env.D.sum() == 0.0  # nothing moved


def test_a_config_with_keyword_arguments_is_one_error_naming_them():
    with pytest.raises(ConfigError) as err:
        SwarmAllocationEnv(AllocConfig(**SMALL), client=object(), n_defenders=20, grid_size=4)
    message = str(err.value)
    assert len(message.splitlines()) == 1
    assert "grid_size" in message and "n_defenders" in message
    assert SwarmAllocationEnv(client=object(), **SMALL).config == AllocConfig(**SMALL)  # either alone is fine
    assert SwarmAllocationEnv(AllocConfig(**SMALL), client=object()).config == AllocConfig(**SMALL)


@pytest.fixture
def opened(monkeypatch):
    """Every StatsStore opened during the test, whichever object of the client holds it."""
    stores = []
    init = StatsStore.__init__

    def record(self, *args, **kwargs):
        init(self, *args, **kwargs)
        stores.append(self)

    monkeypatch.setattr(StatsStore, "__init__", record)
    return stores


def test_close_closes_the_store_of_a_client_the_env_made(tmp_path, opened):
    env = SwarmAllocationEnv(AllocConfig(**SMALL), store=tmp_path / "s.sqlite")
    env.reset(seed=0)
    env.step(stay(env))
    assert len(opened) == 1 and opened[0].db.execute("select 1").fetchone() == (1,)
    env.close()
    with pytest.raises(sqlite3.ProgrammingError):
        opened[0].db.execute("select 1")
    env.close()  # a second close is allowed (gymnasium's checker asks for it)


def test_close_leaves_a_given_client_open(tmp_path, opened):
    client = CaptureTimeClient(AllocConfig(**SMALL).game_settings(), local_store=tmp_path / "s.sqlite")
    env = SwarmAllocationEnv(AllocConfig(**SMALL), client=client)
    env.reset(seed=0)
    env.close()
    assert len(opened) == 1 and opened[0].db.execute("select 1").fetchone() == (1,)
    client.close()


def test_every_attribute_is_made_in_init(tmp_path):
    env = SwarmAllocationEnv(AllocConfig(**SMALL), store=tmp_path / "s.sqlite")
    made = set(vars(env))
    assert env.eliminated == 0.0 and env.breached == 0.0 and env.steps == 0
    _, info = env.reset(seed=0)
    assert info["eliminated"] == 0.0
    _, _, _, _, info = env.step(stay(env))
    assert info["engaged_cells"] == 0 and info["eliminated"] == env.eliminated == 0.0
    later = set(vars(env))
    # Only gymnasium's generator, declared (None) on gym.Env and made at the first reset, comes later.
    assert made <= later and later - made <= set(vars(gymnasium.Env))
    env.close()
