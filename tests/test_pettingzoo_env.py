"""The two-learner envs (farm.alloc.envs.pettingzoo_env) as PettingZoo's users expect them: PettingZoo's
own API and seed tests, zero-sum rewards, what the follower intruders see, the single env's
episode to the bit when the intruders route by the drift law, and bad actions refused. No Ray:
a stand-in client, or an in-process one over a store warmed here."""

import ast
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from helpers import Answers
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

from farm.alloc import SCENARIOS, AllocConfig, SwarmAllocationEnv
from farm.alloc.envs.pettingzoo_env import (
    AGENTS,
    SwarmAllocationAECEnv,
    SwarmAllocationParallelEnv,
    env,
    parallel_env,
    raw_env,
)
from farm.alloc.game.dynamics import Layout, observe
from farm.core.errors import ActionError, ConfigError

ROOT = Path(__file__).resolve().parent.parent
SMALL = {"grid_size": 3, "n_defenders": 10, "n_intruders": 5}
NAMING = "We recommend agents to be named"  # PettingZoo's advice for names like player_0; ours are the sides


def small(**settings):
    """The keyword arguments of a small game answered by Answers."""
    return dict(SMALL, **settings, client=Answers())


def only_naming_warnings(caught):
    """The warnings caught, but PettingZoo's advice on agent names."""
    return [str(w.message) for w in caught if NAMING not in str(w.message)]


@pytest.mark.parametrize("make", [env, raw_env], ids=["env", "raw_env"])
def test_pettingzoo_api_test_passes_on_the_aec_env(make):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        api_test(make(**small()), num_cycles=50)
    assert only_naming_warnings(caught) == []


def test_pettingzoo_parallel_api_test_passes():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(parallel_env(**small()), num_cycles=50)
    assert only_naming_warnings(caught) == []


def test_pettingzoo_seed_tests_pass():
    seed_test(lambda: env(**small()), num_cycles=20)
    parallel_seed_test(lambda: parallel_env(**small()), num_cycles=20)


def test_spaces_and_agents():
    game = raw_env(**small())
    layout = Layout(3)
    assert game.possible_agents == list(AGENTS) == ["defenders", "intruders"] and game.agents == []
    assert game.action_space("defenders").shape == (49,) == (len(layout.src),)
    assert game.action_space("intruders").shape == (21,) == (len(layout.route_src),)
    for agent in AGENTS:
        assert game.observation_space(agent).shape == (18,) and game.observation_space(agent).dtype == np.float32
        assert game.action_space(agent).dtype == np.float32
    game.reset(seed=0)
    assert game.agent_selection == "defenders" and game.agents == list(AGENTS)


def random_actions(game, rng):
    """An action of each agent, drawn uniformly from [-2, 2] (the env clips to [-1, 1])."""
    return {agent: rng.uniform(-2, 2, game.action_space(agent).shape).astype(np.float32) for agent in AGENTS}


def test_rewards_are_zero_sum_and_each_agent_gets_its_reward_at_its_turn(rng):
    game = env(**small(c_capture=1.5))
    rewards = []
    for seed in range(3):
        game.reset(seed=seed)
        previous = None
        for agent in game.agent_iter():
            _, reward, terminated, truncated, _ = game.last()
            if previous is not None:  # since the agent last acted: the step's reward, its side's
                assert reward == (previous if agent == "defenders" else -previous)
            if terminated or truncated:
                game.step(None)
                continue
            game.step(random_actions(game, rng)[agent])
            if agent == "intruders":  # the step's end
                assert game.rewards["defenders"] + game.rewards["intruders"] == 0.0
                previous = game.rewards["defenders"]
                rewards.append(previous)
            else:
                assert game.rewards == {"defenders": 0.0, "intruders": 0.0}
        assert game.agents == []
    assert len(set(rewards)) > 3  # the rewards vary: the test saw real ones
    par = parallel_env(**small(c_capture=1.5))
    par.reset(seed=0)
    while par.agents:
        _, step_rewards, *_ = par.step(random_actions(par, rng))
        assert set(step_rewards) == set(AGENTS) and step_rewards["defenders"] + step_rewards["intruders"] == 0.0


def to_neighbour(game):
    """The defenders' action (shifted map) sending every cell's mass one column right where it can, else staying."""
    layout = game.unwrapped.layout
    right = (layout.dst == layout.src + 1) & (layout.dst // game.unwrapped.n == layout.src // game.unwrapped.n)
    stays = layout.dst == layout.src
    keeps = ~np.isin(layout.src, layout.src[right])
    return np.where(right | (stays & keeps), 1.0, -1.0).astype(np.float32)


def test_the_follower_intruders_observe_the_defenders_after_their_move(rng):
    game = raw_env(**small(action_map="shifted"))
    game.reset(seed=1)
    before = game.observe("defenders")
    assert np.array_equal(game.observe("intruders"), before)  # nothing has moved yet
    game.step(to_neighbour(game))
    seen, cells = game.observe("intruders"), 9
    base = game.layout.base
    assert before[base] == 1.0 and seen[base] == 0.0 and seen[base + 1] == 1.0  # D': the base's mass moved right
    assert np.array_equal(seen[cells:], before[cells:])  # the intruders themselves have not moved
    assert np.array_equal(seen, observe(game.moved[None], game.I[None])[0])
    assert np.array_equal(game.observe("defenders"), before)  # the step's start, until the intruders act
    assert np.array_equal(game.state(), seen)

    blind = raw_env(**small(action_map="shifted", information="simultaneous"))
    blind.reset(seed=1)
    blind.step(to_neighbour(blind))
    assert blind.information == "simultaneous" and np.array_equal(blind.observe("intruders"), before)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store warmed here for outnumbered_3x3's lattice of team sizes (the envs' clients open it)."""
    from farm.alloc.game.lattice import memo_client

    path = tmp_path_factory.mktemp("pettingzoo") / "alloc.sqlite"
    client, pairs, _ = memo_client([SCENARIOS["outnumbered_3x3"].config()], "local", path)
    client.close()
    assert pairs and path.is_file()
    return path


def drift_action(layout: Layout, drift: float) -> np.ndarray:
    """The intruders' action whose routing under `action_map: shifted` is the drift law exactly:
    (R,) float32 a = 2 p - 1, p each route's share; each cell's a + 1 = 2 p sums to 2, so the
    map's p = (a + 1) / 2 gives back the shares to the bit."""
    rows = layout.route_src // layout.n
    edge = (rows == 0) | (rows == layout.n - 1)
    p = np.where(layout.route_row == 0, np.where(edge, 1.0 - drift, 1.0 - 2.0 * drift), drift)
    return (2.0 * p - 1.0).astype(np.float32)


def same(a, b) -> bool:
    """Equal to the bit: arrays by their bytes, anything else by its repr (floats round-trip)."""
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.tobytes() == b.tobytes()
    return type(a) is type(b) and repr(a) == repr(b)


@pytest.mark.slow
@pytest.mark.parametrize("drift", [0.0, 0.25])
def test_an_episode_with_drift_routing_is_the_single_env_episode_to_the_bit(store, rng, drift):
    config = SCENARIOS["outnumbered_3x3"].config(action_map="shifted", vertical_drift=drift)
    single = SwarmAllocationEnv(config, store=store)
    aec, par = raw_env(config, store=store), parallel_env(config, store=store)
    drifting = drift_action(aec.layout, drift)
    engaged = 0
    for seed in (0, 7, 2026):
        obs, info = single.reset(seed=seed)
        aec.reset(seed=seed)
        par_obs, par_infos = par.reset(seed=seed)
        for agent in AGENTS:
            assert same(aec.observe(agent), obs) and same(par_obs[agent], obs)
            assert same(aec.infos[agent], info) and same(par_infos[agent], info)
        while True:
            action = rng.uniform(-1, 1, single.action_space.shape).astype(np.float32)
            obs, reward, terminated, truncated, info = single.step(action)
            aec.step(action)
            aec.step(drifting)
            par_obs, par_rewards, par_terminated, par_truncated, par_infos = par.step(
                {"defenders": action, "intruders": drifting})
            assert same(aec.rewards["defenders"], reward) and same(aec.rewards["intruders"], -reward)
            assert same(par_rewards["defenders"], reward) and same(par_rewards["intruders"], -reward)
            for agent in AGENTS:
                assert same(aec.observe(agent), obs) and same(par_obs[agent], obs)
                assert aec.terminations[agent] is terminated is par_terminated[agent]
                assert aec.truncations[agent] is truncated is par_truncated[agent]
                assert same(aec.infos[agent], info) and same(par_infos[agent], info)
            engaged += info["engaged_cells"]
            if terminated or truncated:
                break
        assert par.agents == [] and aec.agents == list(AGENTS)  # the AEC agents leave by their dead steps
        aec.step(None)
        aec.step(None)
        assert aec.agents == []
    assert engaged > 0  # the episodes held engagements: the store's answers were used
    for e in (single, aec, par):
        e.close()


def test_the_simultaneous_aec_env_plays_the_parallel_env_game(rng):
    aec, par = raw_env(**small(information="simultaneous")), parallel_env(**small())
    aec.reset(seed=3)
    obs, _ = par.reset(seed=3)
    while par.agents:
        actions = random_actions(par, rng)
        for agent in AGENTS:
            assert same(aec.observe(agent), obs[agent])
            aec.step(actions[agent])
        obs, rewards, *_ = par.step(actions)
        assert same(aec.rewards, rewards)


def test_the_start_is_the_single_env_start_and_unseeded_resets_go_on_with_the_generator(rng):
    single, aec, par = SwarmAllocationEnv(**small()), raw_env(**small()), parallel_env(**small())
    for seed in (0, None, None, 11, None):
        obs, _ = single.reset(seed=seed)
        aec.reset(seed=seed)
        par_obs, _ = par.reset(seed=seed)
        assert same(aec.observe("defenders"), obs) and same(par_obs["defenders"], obs)
        while par.agents:  # an episode played between the resets draws nothing
            actions = random_actions(par, rng)
            single.step(actions["defenders"])
            aec.step(actions["defenders"])
            aec.step(actions["intruders"])
            par.step(actions)


def snapshot(game) -> str:
    """Everything a step may change, as one text."""
    e = game.unwrapped
    fields = {name: getattr(e, name, None) for name in ("D", "I", "moved", "steps", "breached", "eliminated",
                                                         "agents", "agent_selection", "rewards", "terminations",
                                                         "truncations", "infos", "_cumulative_rewards")}
    fields["rng"] = e.np_random.bit_generator.state
    return repr(fields)


BAD = {"shape": (lambda k: np.zeros(k + 1), "got shape"), "nan": (lambda k: np.full(k, np.nan), "not finite"),
       "inf": (lambda k: np.full(k, -np.inf), "not finite"), "text": (lambda k: ["x"] * k, "got dtype <U1"),
       "bool": (lambda k: np.zeros(k, dtype=bool), "got dtype bool")}


@pytest.mark.parametrize("bad", BAD)
def test_a_bad_aec_action_is_refused_in_one_line_naming_it_and_changes_nothing(rng, bad):
    make, problem = BAD[bad]
    game = env(**small())
    game.reset(seed=0)
    for agent in AGENTS:  # a step played first: each agent holds a reward
        game.step(random_actions(game, rng)[agent])
    for agent in AGENTS:
        assert game.unwrapped._cumulative_rewards[agent] != 0.0
        before = snapshot(game)
        with pytest.raises(ActionError) as err:
            game.step(make(game.action_space(agent).shape[0]))
        message = str(err.value)
        assert len(message.splitlines()) == 1 and message.startswith(f"{agent}' action: ") and problem in message
        assert snapshot(game) == before
        game.step(random_actions(game, rng)[agent])  # a good action then plays on


@pytest.mark.parametrize("actions, where", [
    ({"defenders": np.zeros(49)}, "actions: "),
    ({"defenders": np.zeros(49), "intruders": np.zeros(21), "referee": 0}, "actions: "),
    ([np.zeros(49), np.zeros(21)], "actions: "),
    ({"defenders": np.zeros(48), "intruders": np.zeros(21)}, "actions['defenders']: "),
    ({"defenders": np.zeros(49), "intruders": [np.nan] * 21}, "actions['intruders']: "),
], ids=["missing", "extra", "list", "defenders", "intruders"])
def test_bad_parallel_actions_are_refused_in_one_line_naming_them_and_change_nothing(actions, where):
    game = parallel_env(**small())
    game.reset(seed=0)
    before = snapshot(game)
    with pytest.raises(ActionError) as err:
        game.step(actions)
    assert len(str(err.value).splitlines()) == 1 and str(err.value).startswith(where)
    assert snapshot(game) == before


def test_step_before_reset_or_after_the_end_is_an_error(rng):
    for game in (raw_env(**small()), parallel_env(**small())):
        with pytest.raises(ResetNeeded):
            game.step(None if isinstance(game, SwarmAllocationAECEnv) else random_actions(game, rng))
    game = parallel_env(**small())
    game.reset(seed=0)
    while game.agents:
        game.step(random_actions(game, rng))
    with pytest.raises(ResetNeeded):
        game.step(random_actions(game, rng))


def test_constructors_and_their_refusals():
    assert isinstance(raw_env(**small()), SwarmAllocationAECEnv)
    assert isinstance(env(**small()).unwrapped, SwarmAllocationAECEnv)
    assert isinstance(parallel_env(**small()), SwarmAllocationParallelEnv)
    assert raw_env(AllocConfig(**SMALL), client=Answers()).config == AllocConfig(**SMALL)
    assert parallel_env(**small(information="follower")).information == "simultaneous"
    frame = raw_env(**small(), render_mode="rgb_array")
    frame.reset(seed=0)
    assert frame.render().shape == (96, 96, 3) and raw_env(**small()).render() is None
    for make in (raw_env, parallel_env):
        refusals = [(dict(small(intruders="least_defended")), "intruders"),
                    (dict(small(), render_mode="human"), "render_mode"),
                    (dict(small(), config=AllocConfig(**SMALL)), "grid_size")]
        for kwargs, field in refusals:
            with pytest.raises(ConfigError) as err:
                make(**kwargs)
            assert len(str(err.value).splitlines()) == 1 and field in str(err.value)


def imports_pettingzoo_at_module_level(path: Path) -> bool:
    """Whether the module at path imports pettingzoo or farm.alloc.envs.pettingzoo_env outside every function."""

    def named(node) -> list[str]:
        if isinstance(node, ast.Import):
            return [a.name for a in node.names]
        return [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]

    def visit(node) -> bool:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)) and any(
                    n.split(".")[0] == "pettingzoo" or n.startswith("farm.alloc.envs.pettingzoo_env")
                    for n in named(child)):
                return True
            if visit(child):
                return True
        return False

    return visit(ast.parse(path.read_text()))


def test_nothing_else_in_farm_imports_pettingzoo_at_import_time(tmp_path):
    checked = sorted(p for p in (ROOT / "farm").rglob("*.py") if p.name != "pettingzoo_env.py")
    assert [str(p.relative_to(ROOT)) for p in checked if imports_pettingzoo_at_module_level(p)] == []
    planted = tmp_path / "planted.py"  # the check finds one
    planted.write_text("def f():\n    import pettingzoo\n\n\n"
                       "if True:\n    from farm.alloc.envs import pettingzoo_env\n")
    assert imports_pettingzoo_at_module_level(planted)
    # Without pettingzoo, farm imports and pettingzoo_env says in one line what to install.
    script = ("import sys; sys.modules['pettingzoo'] = None\n"
              "import farm, farm.alloc, farm.alloc.envs.defenders, farm.alloc.envs.vector\n"
              "try:\n    import farm.alloc.envs.pettingzoo_env\nexcept ModuleNotFoundError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True, text=True, cwd=ROOT,
                         timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == [
        "farm.alloc.envs.pettingzoo_env needs pettingzoo: pip install 'swarm-farm[marl]'"]
