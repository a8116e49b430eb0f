"""The policy registry: kinds numbered by the registry, the compiled dispatch generated
from it (an error for a kind no policy has), and a policy defined here, in a test file,
registered and played by simulate_games without an edit to any other file."""

import importlib

import numpy as np
import pytest
from numba import njit

import workers
from workers import Case, InputError, simulate_games
from workers.compiled import kernel_cache_dir
from workers.engine import _controls, _kernels, _play, _step_velocities
from workers.policies.registry import (
    EVADER_POLICIES,
    EVADERS,
    PURSUER_POLICIES,
    PURSUERS,
    dispatch_source,
    evader_velocity,
    get_evader_policy,
    get_pursuer_policy,
    pursuer_velocity,
    register_policy,
    unregister_policy,
)

TEAMS = [("pursuer", PURSUERS, PURSUER_POLICIES, pursuer_velocity),
         ("evader", EVADERS, EVADER_POLICIES, evader_velocity)]


@pytest.mark.parametrize("team, names, table, compiled", TEAMS)
def test_kinds_are_positions_in_the_registry(team, names, table, compiled):
    assert list(table) == list(names)
    for kind, name in enumerate(names):
        module = importlib.import_module(f"workers.policies.{name}")
        assert table[name] == (name, kind, module.NEEDS_CELLS, getattr(module, name))
    assert sorted(p.kind for p in table.values()) == list(range(len(names)))


@pytest.mark.parametrize("team, names, table, compiled", TEAMS)
def test_the_compiled_dispatch_is_generated_from_the_registry(team, names, table, compiled):
    source = dispatch_source(team, len(names))
    branches = [f"    if kind == {k}:\n        return policy_{k}(agent, s)\n" for k in range(len(names))]
    assert source == f"def {team}_velocity(kind, agent, s):\n" + "".join(branches) + (
        f"    raise ValueError('unknown {team} policy kind: not one of workers.policies.registry')\n")
    # the dispatch the cached kernels inline is that source over the registry's functions, in kind order
    namespace = compiled.py_func.__globals__
    assert [namespace[f"policy_{k}"] for k in range(len(names))] == [table[n].fn for n in names]
    assert f"policy_{len(names)}" not in namespace
    assert _controls.py_func.__globals__[f"{team}_velocity"] is compiled


def test_an_unknown_kind_is_an_error_in_compiled_code():
    P, E, alive = np.array([[[4.0, 5.0]]]), np.array([[[8.0, 5.0]]]), np.array([[True]])
    args = (False, np.array([0.0, 5.0]), 0.01, 1.0, 1.0, np.ascontiguousarray(workers.DEFAULT_ARENA.vertices))
    up, ue = _step_velocities(P, E, alive, len(PURSUERS) - 1, len(EVADERS) - 1, *args)  # the last kinds are known
    assert up.shape == (1, 1, 2) and ue.shape == (1, 1, 2)
    with pytest.raises(ValueError, match="unknown pursuer policy kind"):
        _step_velocities(P, E, alive, len(PURSUERS), 0, *args)
    with pytest.raises(ValueError, match="unknown evader policy kind"):
        _step_velocities(P, E, alive, 0, len(EVADERS), *args)
    with pytest.raises(ValueError, match="unknown pursuer policy kind"):
        _step_velocities(P, E, alive, -1, 0, *args)


def test_an_unknown_name_is_an_input_error_naming_the_field():
    with pytest.raises(InputError, match=r"^pursuer_policy: unknown policy 'nope' \(choose from area_min, pure"):
        get_pursuer_policy("nope")
    with pytest.raises(InputError, match="^evader_policy: unknown policy 'nope'"):
        get_evader_policy("nope")
    with pytest.raises(InputError, match="^evader_policy: unknown policy 'area_min'"):
        simulate_games([[[4.0, 5.0]]], [[[8.0, 5.0]]], evader_policy="area_min")


# ---------------------------------------------------------------- a policy defined here
@njit(inline="always")
def stand_still(j, s):
    """Pursuer: stay where it is."""
    return 0.0, 0.0


@njit
def run_right(i, s):
    """Evader: run in +x at its team's speed."""
    return s.ve, 0.0


@pytest.fixture
def registered():
    """stand_still and run_right registered for this test only."""
    policies = register_policy("pursuer", stand_still, needs_cells=False), \
        register_policy("evader", run_right, needs_cells=False)
    try:
        yield policies
    finally:
        unregister_policy("evader", "run_right")
        unregister_policy("pursuer", "stand_still")
    assert list(PURSUER_POLICIES) == list(PURSUERS) and list(EVADER_POLICIES) == list(EVADERS)


def engine_cache_files() -> dict:
    """The engine's files in the kernels' on-disk cache, with their sizes and times."""
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in kernel_cache_dir().rglob("engine.*")}


@pytest.mark.slow
def test_a_policy_registered_in_a_test_file_plays_through_simulate_games(registered):
    pp, ep = registered
    assert (pp.kind, ep.kind) == (len(PURSUERS), len(EVADERS))
    assert Case(1, 1, pursuer_policy="stand_still", evader_policy="run_right").validate()
    P, E = np.array([[[1.0, 5.0], [2.0, 2.0]]]), np.array([[[5.0, 5.0]]])
    built_in = simulate_games(P, E, t_max=3.0, record=True)  # the cached kernels, as before
    before = engine_cache_files()

    res = simulate_games(P, E, pursuer_policy="stand_still", evader_policy="run_right", t_max=3.0, evader_speed=2.0,
                         record=True)
    assert res.steps[0] == 300 and np.isnan(res.capture_times).all()
    np.testing.assert_array_equal(res.pursuer_paths[-1, 0], P[0])  # never moved
    np.testing.assert_allclose(res.evader_paths[200, 0, 0], [9.0, 5.0])  # 2 per unit time, for 2 units
    np.testing.assert_array_equal(res.evader_paths[-1, 0, 0], [10.0, 5.0])  # then held at the wall
    # a registered policy plays against a built-in one (the same fresh kernels)
    mixed = simulate_games(P, E, evader_policy="run_right", t_max=20.0)
    assert 500 < mixed.capture_step[0, 0] < 2000

    # those kernels are fresh copies, not cached on disk; built-in games still use the cached
    # kernels, with the same numbers
    fresh = _kernels(pp, ep)
    assert fresh[0] is not _play and type(fresh[0]._cache).__name__ == "NullCache"
    assert _kernels(get_pursuer_policy("area_min"), get_evader_policy("centroid")) == (_play, _step_velocities)
    assert type(_play._cache).__name__ == "FunctionCache"
    again = simulate_games(P, E, t_max=3.0, record=True)
    assert engine_cache_files() == before
    np.testing.assert_array_equal(again.evader_paths, built_in.evader_paths)
    np.testing.assert_array_equal(again.capture_step, built_in.capture_step)


def test_register_checks_its_arguments(registered):
    with pytest.raises(InputError, match="^pursuer_policy: 'stand_still' is already a policy"):
        register_policy("pursuer", stand_still, needs_cells=False)
    with pytest.raises(InputError, match="^evader_policy: 'plain' must be a numba-compiled function"):
        register_policy("evader", run_right.py_func, needs_cells=False, name="plain")
    with pytest.raises(InputError, match="^team: must be 'pursuer' or 'evader'"):
        register_policy("referee", stand_still, needs_cells=False)
    with pytest.raises(InputError, match="^pursuer_policy: only the last registered policy"):
        unregister_policy("pursuer", "area_min")
