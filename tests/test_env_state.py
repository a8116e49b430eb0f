"""One rule for what set_state takes (farm.alloc.envs.defenders.check_state), in the single env and the
batched one alike (and the intruders' envs built on them): densities that are not finite numbers
>= 0, counters that are not numbers, or a state of another shape are one line naming set_state,
the env unchanged, and the batched env's next step never sees them. In process, no Ray."""

import copy

import numpy as np
import pytest

from farm.alloc import AllocConfig
from farm.core.errors import ConfigError

CFG = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)


def make(kind: str, store: str):
    from farm.alloc.envs.defenders import SwarmAllocationEnv
    from farm.alloc.envs.intruders import SwarmIntruderEnv, SwarmIntruderVectorEnv
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv

    return {"single": lambda: SwarmAllocationEnv(CFG, store=store),
            "batched": lambda: SwarmAllocationVectorEnv(CFG, 2, store=store),
            "intruders": lambda: SwarmIntruderEnv(CFG, store=store),
            "intruders batched": lambda: SwarmIntruderVectorEnv(CFG, 2, store=store)}[kind]()


KINDS = ["single", "batched", "intruders", "intruders batched"]
DENSITIES = {"NaN": np.nan, "negative": -0.25, "infinite": np.inf}


def with_density(state: dict, side: str, value: float) -> dict:
    bad = copy.deepcopy(state)
    values = np.array(bad[side], dtype=np.float64)
    values.reshape(-1)[1] = value
    bad[side] = values
    return bad


def assert_unchanged(env, before: dict) -> None:
    after = env.get_state()
    for key in ("D", "I", "steps", "breached", "eliminated"):
        np.testing.assert_array_equal(after[key], before[key])


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("side", ["D", "I"])
@pytest.mark.parametrize("value", DENSITIES)
def test_densities_that_are_not_finite_and_non_negative_are_refused_by_every_env(store, kind, side, value):
    env = make(kind, store)
    try:
        env.reset(seed=0)
        before = env.get_state()
        with pytest.raises(ConfigError) as e:
            env.set_state(with_density(before, side, DENSITIES[value]))
        assert str(e.value) == f"set_state: the state's densities {side} must be finite numbers >= 0"
        assert_unchanged(env, before)
    finally:
        env.close()


def test_the_batched_env_never_steps_from_a_state_the_single_env_refuses(store):
    """The batched env refuses the state; its next step's observations and rewards stay finite."""
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv

    env = SwarmAllocationVectorEnv(CFG, 2, store=store)
    try:
        env.reset(seed=0)
        with pytest.raises(ConfigError):
            env.set_state(with_density(env.get_state(), "D", np.nan))
        obs, rewards, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rewards))
    finally:
        env.close()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("field, value, problem", [
    ("steps", -1, "steps must be whole numbers >= 0"),
    ("steps", 1.5, "steps must be whole numbers >= 0"),
    ("breached", np.nan, "breached must be finite numbers"),
    ("eliminated", "a lot", "eliminated must be finite numbers"),
    ("engagements", -3, "engagements must be a whole number >= 0"),
])
def test_counters_that_are_not_numbers_are_refused_by_every_env(store, kind, field, value, problem):
    env = make(kind, store)
    try:
        env.reset(seed=0)
        before = env.get_state()
        bad = copy.deepcopy(before)
        batched = np.ndim(before["D"]) == 2
        bad[field] = np.full(2, value, dtype=object if isinstance(value, str) else None) \
            if batched and field != "engagements" else value
        with pytest.raises(ConfigError) as e:
            env.set_state(bad)
        assert str(e.value).startswith(f"set_state: the state's {problem}")
        assert_unchanged(env, before)
    finally:
        env.close()


@pytest.mark.parametrize("kind", KINDS)
def test_a_state_that_is_not_a_dict_is_one_line(store, kind):
    env = make(kind, store)
    try:
        with pytest.raises(ConfigError, match=r"^set_state: expected the dict get_state\(\) returns, got list$"):
            env.set_state([1, 2, 3])
    finally:
        env.close()


@pytest.mark.parametrize("batched", [False, True])
@pytest.mark.parametrize("draw", [{"member": 7}, {"member": "x"}, {"rng": {"bit_generator": "PCG64", "state": None}}])
def test_a_damaged_draw_of_a_mixture_is_one_line_the_env_unchanged(store, batched, draw):
    """Intruders drawn per episode from a mixture of two: a draw of a member that is not one, or of
    a generator state that is not one, is refused before anything of the state is taken."""
    from farm.alloc.envs.defenders import SwarmAllocationEnv
    from farm.alloc.envs.vector import SwarmAllocationVectorEnv

    cfg = CFG.model_copy(update={"intruders": "mixture",
                                 "intruder_options": {"members": ["fewest_ahead", "split_away"]}})
    env = SwarmAllocationVectorEnv(cfg, 2, store=store) if batched else SwarmAllocationEnv(cfg, store=store)
    try:
        env.reset(seed=0)
        before = env.get_state()
        key = "intruder_draws" if batched else "intruder_draw"
        assert key in before
        bad = copy.deepcopy(before)
        bad["D"] = np.asarray(bad["D"]) * 0.5
        if batched:
            bad[key][0] = draw
        else:
            bad[key] = draw
        with pytest.raises(ConfigError) as e:
            env.set_state(bad)
        assert str(e.value).startswith("set_state: the state's draw of the frozen side is damaged (")
        assert_unchanged(env, before)
        assert repr(env.get_state()[key]) == repr(before[key])
    finally:
        env.close()
