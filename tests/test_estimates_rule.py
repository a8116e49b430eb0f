"""The timing-independent estimate rule (`estimates: lattice`, issue 19): whether a visit is
estimated, and its value, depend only on the team sizes, never on what the service has
computed by then; the service's own rule (`estimates: true`) does depend on it."""

import json

import numpy as np
import pytest

from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.alloc.training import TrainConfig
from farm.core.config import ConfigError
from farm.service import CaptureTimeClient
from farm.service.keys import LATTICE, lattice_anchors
from farm.service.lookup import estimate

CFG = dict(grid_size=3, n_defenders=10, n_intruders=7, games=3)
PAIRS = [(5, 7), (3, 4), (10, 5), (5, 7), (7, 1)]


def test_anchors_are_the_corners_of_the_lattice_cell():
    assert lattice_anchors(4, 8) == [(4, 8)]
    assert lattice_anchors(5, 8) == [(4, 8), (6, 8)]
    assert lattice_anchors(5, 7) == [(4, 6), (4, 8), (6, 6), (6, 8)]
    assert lattice_anchors(300, 1) == [(256, 1)]
    for n in range(1, 300):  # every size lies between its anchors
        a = [p for p, _ in lattice_anchors(n, 1)]
        assert min(a) <= min(n, LATTICE[-1]) <= max(a) and all(v in LATTICE for v in a)


def flat(values) -> list[str]:
    """The values' statistics as text (NaN equals NaN there)."""
    return [json.dumps(v.flat(), sort_keys=True) for v in values]


def client(path):
    return CaptureTimeClient(AllocConfig(**CFG).game_settings(), local_store=path)


def test_lattice_rule_answers_do_not_depend_on_what_the_store_holds(tmp_path):
    cold = client(tmp_path / "cold.sqlite")
    warm = client(tmp_path / "warm.sqlite")
    warm.get_many([(5, 7), (3, 4), (10, 5), (7, 1)])  # the exact values are there already
    a, b = cold.get_many(PAIRS, estimate="lattice"), warm.get_many(PAIRS, estimate="lattice")
    assert flat(a) == flat(b)
    assert [v.estimate is not None for v in a] == [True, False, True, True, True]  # (3, 4) is on the lattice
    # an off-lattice pair is its anchors' interpolation, the same answer for the client's life
    key = cold.key(5, 7)
    expected = estimate(key, [(p, e, cold.get(p, e)) for p, e in lattice_anchors(5, 7)])
    assert flat([a[0]]) == flat([expected]) and a[3] is a[0]
    assert cold.get_many([(5, 7)], estimate="lattice")[0] is a[0]
    # the service's own rule answers the warm store's exact value: it depends on the store
    assert warm.get_many([(5, 7)], estimate=True)[0].estimate is None
    assert cold.get_many([(9, 7)], estimate=True)[0].estimate is not None
    cold.close()
    warm.close()


def test_an_episode_with_lattice_estimates_is_the_same_on_any_store(tmp_path):
    def episode(path, prefill):
        c = client(path)
        if prefill:
            c.get_many([(p, e) for p in range(1, 11) for e in range(1, 8)])
        env = SwarmAllocationEnv(AllocConfig(**CFG), client=c, estimates="lattice")
        env.reset(seed=3)
        rng = np.random.default_rng(0)
        out = []
        for _ in range(3):
            _, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
            out.append((r, info["estimates"], info["eliminated_step"]))
            if term or trunc:
                break
        env.close()
        c.close()
        return out

    cold = episode(tmp_path / "a.sqlite", False)
    assert sum(estimated for _, estimated, _ in cold) > 0  # the rule was used
    assert cold == episode(tmp_path / "b.sqlite", True)


def test_the_setting_is_checked():
    assert TrainConfig(name="t", service={"estimates": "lattice"}).service.estimates == "lattice"
    with pytest.raises(ValueError, match="estimates"):
        TrainConfig(name="t", service={"estimates": "sometimes"})
    with pytest.raises(ConfigError, match="^estimates: must be false, true or 'lattice', got 'yes'"):
        SwarmAllocationEnv(AllocConfig(**CFG), client=object(), estimates="yes")
