"""The allocator registry (farm.alloc.allocators) is the one list every evaluation takes: an
allocator defined and registered here, in a test file, is evaluated by `farm eval`'s loop,
by the suite (on Ray workers) and by an experiment's trials (Tune actors), with no other edit.

The allocator sends every cell's defenders one step up: a behaviour no built-in allocator has,
so its rows are its own (their numbers are checked against the same loop run here)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from farm.alloc.allocators import (
    Spec,
    allocator_entry,
    allocator_names,
    make_allocator,
    register_allocator,
    unregister_allocator,
)
from farm.alloc.envs.defenders import moves
from farm.alloc.evaluation.rollout import evaluate_policies
from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
NAME = "north_wind"


class NorthWind:
    """Every cell's defenders go one row up (stay on the top row)."""

    def __init__(self, config, client=None, *, strength: float = 1.0):
        self.n = config.grid_size
        self.src, self.dst, _ = moves(self.n)
        self.strength = strength

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        up = (self.dst == self.src - self.n) | ((self.src < self.n) & (self.dst == self.src))
        return np.where(up, self.strength, -1.0).astype(np.float32), state


@pytest.fixture
def north_wind():
    """NorthWind registered as a planner (it has an option), for one test."""
    register_allocator(NAME, NorthWind, kind="planner")
    try:
        yield
    finally:
        unregister_allocator(NAME)


def test_registration_lists_it_once_after_the_built_ins_and_makes_it(north_wind):
    names = allocator_names(("baseline", "planner"))
    assert names[:6] == ["stay_at_base", "greedy_nearest", "spread_evenly", "intercept", "mmr", "receding_horizon"]
    assert names[-1] == NAME and names.count(NAME) == 1
    assert allocator_entry(NAME).options() == ["strength"]
    config = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5, games=3)
    assert isinstance(make_allocator(NAME, config, None, strength=0.5), NorthWind)
    with pytest.raises(ValueError, match="registered already"):
        register_allocator(NAME, NorthWind, kind="planner")
    with pytest.raises(ValueError, match="kind: must be one of"):
        register_allocator("other", NorthWind, kind="oracle")


def test_an_unknown_allocator_is_one_line_naming_the_choices():
    with pytest.raises(ConfigError, match=r"policy: unknown allocator 'nobody' \(choose from stay_at_base, "):
        make_allocator("nobody", AllocConfig())
    assert NAME not in allocator_names()  # the fixture's registration does not outlive its test


def _tiny_run(tmp_path: Path) -> Path:
    """A trained run of configs/train/tiny.yaml (200 steps, the service in process), its store in tmp_path."""
    from farm.alloc.training import load_train_config, train

    config = load_train_config(ROOT / "configs" / "train" / "tiny.yaml")
    config = config.model_copy(update={
        "td3": config.td3.model_copy(update={"n_timesteps": 200}),
        "service": config.service.model_copy(update={"store": str(tmp_path / "store.sqlite")})})
    train(config, tmp_path / "run", show_progress=False)
    return tmp_path / "run"


@pytest.mark.slow
def test_farm_eval_evaluates_a_registered_allocator(north_wind, tmp_path):
    from farm.alloc.evaluation.evaluate import evaluate_run
    from farm.alloc.training.runs import RunFolder
    from farm.service.client import CaptureTimeClient

    run = _tiny_run(tmp_path)
    result = evaluate_run(run, episodes=3, seed=1000)
    assert list(result.table["policy"])[-1] == NAME
    table = pd.read_csv(run / "eval_table.csv")
    assert NAME in set(table["policy"]) and (run / f"density_{NAME}.png").exists()
    assert set(pd.read_csv(run / "eval_steps.csv")["policy"]) >= {NAME, "td3"}
    # its row is the loop's, run here on the same episodes
    config = RunFolder(run).read_config()
    client = CaptureTimeClient(config.env.game_settings(), local_store=tmp_path / "store.sqlite")
    try:
        alone, _, _ = evaluate_policies(config.env, {NAME: NorthWind(config.env)}, client, 3, 1000)
    finally:
        client.close()
    mine = table[table["policy"] == NAME].iloc[0]
    for column in ("return_mean", "eliminated_mean", "coverage_mean"):
        assert math.isclose(mine[column], alone.iloc[0][column], rel_tol=0, abs_tol=1e-12)


@pytest.mark.ray
@pytest.mark.slow
def test_the_suite_evaluates_a_registered_allocator_on_ray_workers(north_wind, ray_local, tmp_path):
    from farm.studies.suite import load_suite_config, run_suite

    path = tmp_path / "suite.yaml"
    path.write_text(yaml.safe_dump({"name": "registry", "scenarios": ["paper_3x3_c1_1.5"],
                                    "policies": ["stay_at_base", NAME], "planner_options": {NAME: {"strength": 0.5}},
                                    "episodes": 2, "env": {"games": 3}, "store": str(tmp_path / "store.sqlite")}))
    board, info = run_suite(load_suite_config(path), tmp_path / "out", show_progress=False)
    assert list(board["policy"]) == ["stay_at_base", NAME] and info["tasks"] == 2
    episodes = pd.read_csv(tmp_path / "out" / "episodes.csv")
    assert (episodes["policy"] == NAME).sum() == 2
    doc = json.loads((tmp_path / "out" / "suite.json").read_text())
    assert doc["resolved"]["policies"] == ["stay_at_base", NAME]
    # the task made it with its option: the same numbers as the loop run here with strength 0.5
    from farm.service.client import CaptureTimeClient

    scenario = load_suite_config(path).env_of("paper_3x3_c1_1.5")
    client = CaptureTimeClient(scenario.game_settings(), local_store=tmp_path / "store.sqlite")
    try:
        alone, _, _ = evaluate_policies(scenario, {NAME: NorthWind(scenario, strength=0.5)}, client, 2, 1000)
    finally:
        client.close()
    mine = board[board["policy"] == NAME].iloc[0]
    assert math.isclose(mine["return_mean"], alone.iloc[0]["return_mean"], rel_tol=0, abs_tol=1e-12)


def test_a_suite_refuses_an_unknown_option_of_a_registered_allocator(north_wind, tmp_path):
    from farm.studies.suite import load_suite_config

    path = tmp_path / "suite.yaml"
    path.write_text(yaml.safe_dump({"policies": [NAME], "planner_options": {NAME: {"gust": 2}}}))
    with pytest.raises(ConfigError, match=f"planner_options.{NAME}: unknown option 'gust' \\(choose from strength\\)"):
        load_suite_config(path)


@pytest.mark.ray
@pytest.mark.slow
def test_an_experiment_evaluates_a_registered_allocator_in_its_trials(north_wind, ray_local, tmp_path):
    from farm.studies.experiments import load_experiment_config, run_experiment

    path = tmp_path / "experiment.yaml"
    path.write_text(yaml.safe_dump({"name": "registry", "base": str(ROOT / "configs" / "train" / "tiny.yaml"),
                                    "overrides": {"env.team_sizes": "lattice", "td3.n_timesteps": 150},
                                    "seeds": [0], "episodes": 2, "store": str(tmp_path / "store.sqlite")}))
    trials, summary, _ = run_experiment(load_experiment_config(path), tmp_path / "out", show_progress=False)
    assert len(trials) == 1
    assert {f"{NAME}_return", f"{NAME}_eliminated"} <= set(trials.columns)
    assert f"{NAME}_return" in summary.columns
    table = pd.read_csv(tmp_path / "out" / "trials" / "p0_s0" / "run" / "eval_table.csv")
    assert list(table["policy"])[-1] == NAME
    assert math.isclose(trials[f"{NAME}_return"].iloc[0], table["return_mean"].iloc[-1], rel_tol=0, abs_tol=1e-12)


def test_a_spec_carries_its_entry_to_another_process(north_wind):
    import pickle

    spec = Spec(allocator_entry(NAME), {"strength": 0.25})
    again = pickle.loads(pickle.dumps(spec))
    assert again.name == NAME and again.make(AllocConfig(), None).strength == 0.25
