"""The benchmark suite (issue 18): scenarios as gymnasium ids, training configs naming a
scenario, the suite config's refusals (in the library and through the CLI), and `farm suite`
on a real local Ray: the demo suite from a cold store through the CLI, the report's section,
the same episodes for every policy, identical numbers on a rerun, and evaluations that miss
on a cold store while both CPUs are held by evaluation tasks."""

import contextlib
import io
import json
import os
from pathlib import Path

import gymnasium
import numpy as np
import pandas as pd
import pytest
import yaml
from pydantic import ValidationError
from test_refuses_cli import farm, one_line_error  # the command line's one-line refusals, checked alike

import farm.alloc as _registers_the_gymnasium_ids  # noqa: F401
from farm.alloc.allocators import allocator_names
from farm.alloc.game.scenarios import PAPER_SCENARIOS, SCENARIOS, THEATRES
from farm.alloc.training import TrainConfig, load_train_config
from farm.core.config import ConfigError
from farm.studies.suite import MEASURES, SuiteConfig, available_policies, evaluate_matchup, load_suite_config, run_suite

ROOT = Path(__file__).resolve().parent.parent
DEMO_GAMES = 8  # games per case in the tests' demo suite (the demo's own: the service's 64)
BOARD_COLUMNS = ["scenario", "policy", "episodes", *[f"{m}_{s}" for m in MEASURES for s in ("mean", "ci95")],
                 "seconds_per_step"]


def write(path, doc):
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


# ----------------------------------------------------------------------------- scenarios
def test_every_scenario_is_a_gymnasium_id_making_its_env(tmp_path):
    for name, scenario in SCENARIOS.items():
        env = gymnasium.make(f"farm/{name}-v0", store=tmp_path / "s.sqlite")
        try:
            assert env.unwrapped.config == scenario.config()
            assert env.unwrapped.config.team_sizes == "lattice"
        finally:
            env.close()
    # RL Zoo's env_kwargs: the caller's settings replace the scenario's one by one
    env = gymnasium.make("farm/outnumbered_3x3-v0", c_capture=0.0, games=4, store=tmp_path / "s.sqlite")
    config = env.unwrapped.config
    env.close()
    assert (config.c_capture, config.games) == (0.0, 4)
    assert (config.n_defenders, config.n_intruders) == (SCENARIOS["outnumbered_3x3"].env["n_defenders"],
                                                        SCENARIOS["outnumbered_3x3"].env["n_intruders"])


def test_the_paper_scenarios_are_the_paper_configs_on_the_lattice():
    for name in PAPER_SCENARIOS:
        paper = load_train_config(ROOT / "configs" / "train" / f"{name}.yaml").env
        assert paper.team_sizes == "exact"
        assert SCENARIOS[name].config() == paper.model_copy(update={"team_sizes": "lattice"}), name


def test_every_scenario_has_a_training_config_giving_exactly_its_env():
    reference = load_train_config(ROOT / "configs" / "train" / "larger_5x5.yaml")
    for name in set(SCENARIOS) - set(THEATRES):
        config = load_train_config(ROOT / "configs" / "train" / f"suite_{name}.yaml")
        assert config.scenario == name and config.name == f"suite_{name}"
        assert config.env == SCENARIOS[name].config(), name
        assert (config.td3, config.eval) == (reference.td3, reference.eval)
        assert config.td3.n_timesteps == 20000


def test_a_training_config_names_a_scenario_and_overrides_its_env(tmp_path):
    config = TrainConfig(name="t", scenario="fast_5x5", env={"games": 4, "c_capture": 0.0})
    assert config.env == SCENARIOS["fast_5x5"].config(games=4, c_capture=0.0)
    assert (config.env.evader_speed, config.env.step_seconds, config.env.tau) == (2.0, 5.0, 5.0)
    # a run folder's config.yaml (scenario and the whole env) reads back as the same config
    saved = write(tmp_path / "saved.yaml", json.loads(config.model_dump_json()))
    assert load_train_config(saved) == config
    with pytest.raises(ConfigError) as e:
        load_train_config(write(tmp_path / "bad.yaml", {"name": "t", "scenario": "nope"}))
    line = str(e.value)
    assert "\n" not in line and "scenario: unknown scenario 'nope'" in line and "outnumbered_3x3" in line


# ----------------------------------------------------------------------------- the config
@pytest.mark.parametrize("doc,words", [
    ({"scenarioz": ["paper_3x3_c1_0"]}, ["scenarioz: not a suite field", "choose from", "scenarios"]),
    ({"scenarios": ["paper_3x3_c1_0", "nope"]}, ["scenarios: unknown scenario 'nope'", "outnumbered_3x3"]),
    ({"scenarios": []}, ["scenarios: must name at least one scenario"]),
    ({"policies": ["spread_evenly", "nope"]}, ["policies: unknown policy 'nope'", "stay_at_base", "spread_evenly"]),
    ({"policies": ["td3"]}, ["policies: unknown policy 'td3'", "runs"]),
    ({"policies": ["spread_evenly", "spread_evenly"]}, ["policies:", "named twice"]),
    ({"scenarios": ["paper_3x3_c1_0"], "runs": {"fast_5x5": "results/runs/x"}},
     ["runs.fast_5x5: not a scenario of this suite", "paper_3x3_c1_0"]),
    ({"env": {"grid_size": 1}}, ["env.grid_size", "greater than or equal to 2"]),
    ({"env": {"tau": 3.0}}, ["env.", "tau", "in scenario"]),
    ({"planner_options": {"spread_evenly": {}}}, ["planner_options.spread_evenly: 'spread_evenly' is not a planner"]),
    ({"episodes": 0}, ["episodes:"]),
    ({"episodes": True}, ["episodes:", "bool"]),
])
def test_bad_suite_configs_are_one_line_naming_the_field_and_the_choices(tmp_path, doc, words):
    with pytest.raises(ConfigError) as e:
        load_suite_config(write(tmp_path / "suite.yaml", doc))
    line = str(e.value)
    assert "\n" not in line and line.startswith(str(tmp_path / "suite.yaml")), line
    for w in words:
        assert w in line, line


def test_planner_options_are_checked_by_name_and_by_value_before_ray(tmp_path):
    planners = [p for p in available_policies() if p not in ("stay_at_base", "greedy_nearest", "spread_evenly")]
    if "receding_horizon" not in planners:
        pytest.skip("no receding_horizon planner yet")
    with pytest.raises(ConfigError, match=r"planner_options.receding_horizon: unknown option 'horizonn' "
                                          r"\(choose from horizon"):
        load_suite_config(write(tmp_path / "s.yaml", {"planner_options": {"receding_horizon": {"horizonn": 3}}}))
    config = SuiteConfig(scenarios=["paper_3x3_c1_0"], planner_options={"receding_horizon": {"horizon": 0}})
    with pytest.raises(ConfigError, match=r"^planner_options.receding_horizon: .*horizon"):
        run_suite(config, tmp_path / "out", address="127.0.0.1:1")  # refused before Ray is asked


def test_the_shipped_suites_name_every_scenario_and_default_to_every_policy():
    suite = load_suite_config(ROOT / "configs" / "suite.yaml")
    assert suite.scenario_names() == list(SCENARIOS) and suite.policies is None
    references = allocator_names(("baseline", "planner"), references=True)
    assert suite.allocator_names() == references
    assert set(references) < set(available_policies())  # subregions: listed, not by default
    assert suite.runs == {name: "results/runs/size_free_transport" if name in THEATRES else f"results/runs/suite_{name}"
                          for name in SCENARIOS} and suite.skip_missing_runs
    assert (suite.episodes, suite.seed, suite.store) == (10, 1000, "results/capture_times.sqlite")
    demo = load_suite_config(ROOT / "configs" / "suite_demo.yaml")
    assert demo.scenario_names() == ["paper_3x3_c1_1.5", "outnumbered_3x3"] and demo.policies is None
    assert (demo.episodes, demo.store) == (3, "results/demo/capture_times.sqlite")


@pytest.mark.parametrize("doc,words", [
    ({"scenarios": ["nope"]}, ["scenarios: unknown scenario 'nope'", "paper_3x3_c1_0"]),
    ({"policiez": ["spread_evenly"]}, ["policiez: not a suite field", "policies"]),
    ({"policies": ["nope"]}, ["policies: unknown policy 'nope'", "spread_evenly"]),
])
def test_the_cli_refuses_bad_configs_in_one_line(tmp_path, doc, words):
    one_line_error(farm("suite", write(tmp_path / "s.yaml", doc), "--out", tmp_path / "o"), *words)


def test_the_cli_refuses_bad_flags_and_a_file_as_out(tmp_path):
    config = write(tmp_path / "s.yaml", {"scenarios": ["paper_3x3_c1_0"]})
    one_line_error(farm("suite", config, "--out", tmp_path / "o", "--episodes", 0), "--episodes")
    one_line_error(farm("suite", config, "--out", tmp_path / "o", "--games", 1), "--games", ">= 2")
    (tmp_path / "file").write_text("")
    one_line_error(farm("suite", config, "--out", tmp_path / "file"), "--out", "not a folder")


def test_a_missing_run_folder_is_one_line_before_ray(tmp_path):
    config = SuiteConfig(scenarios=["paper_3x3_c1_0"], runs={"paper_3x3_c1_0": str(tmp_path / "no")})
    with pytest.raises(ConfigError) as e:
        run_suite(config, tmp_path / "o", address="127.0.0.1:1")  # refused before Ray is asked
    line = str(e.value)
    assert line.startswith("runs.paper_3x3_c1_0: ") and "does not exist" in line and "skip_missing_runs" in line
    assert "configs/train/suite_paper_3x3_c1_0.yaml" in line and "\n" not in line


# ----------------------------------------------------------------------------- runs on Ray
def test_a_cell_is_cut_into_tasks_by_its_episodes_cost():
    """matchup_tasks: small maps' cells stay one task, a 32 x 32 map's episodes are a task each,
    an 8 x 8 map's shared evenly; every episode of every cell in exactly one task, in order."""
    from farm.studies.suite.run import TASK_COST, _cost, matchup_tasks

    costs = [_cost(SCENARIOS[name].config()) for name in ("paper_3x3_c1_1.5", "theatre_8x8", "theatre_32x32")]
    assert costs[0] * 20 <= TASK_COST < costs[2]
    tasks = matchup_tasks(costs, 20)
    assert tasks[0] == (0, 0, 20)
    # 8 x 8 cells x 8 steps: 8 a task at most
    assert [t for t in tasks if t[0] == 1] == [(1, 0, 6), (1, 6, 7), (1, 13, 7)]
    assert [t for t in tasks if t[0] == 2] == [(2, k, 1) for k in range(20)]
    for cell in range(3):
        covered = [e for c, first, count in tasks if c == cell for e in range(first, first + count)]
        assert covered == list(range(20))
    assert matchup_tasks([1.0], 1) == [(0, 0, 1)] and matchup_tasks([1e9], 3) == [(0, 0, 1), (0, 1, 1), (0, 2, 1)]


@pytest.fixture(scope="module")
def demo(ray_local, tmp_path_factory):
    """`farm suite configs/suite_demo.yaml --episodes 2 --games 8` through the CLI's main(), in
    this process on conftest's 2-CPU local Ray, from a cold store (the config's relative store
    lands in this fixture's folder; `make demo` runs it with the service's 64 games a case);
    yields (the results folder, the store, its stdout)."""
    from farm.cli import main

    work = tmp_path_factory.mktemp("demo")
    stdout, stderr = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(work)
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(["suite", str(ROOT / "configs" / "suite_demo.yaml"), "--episodes", "2", "--games",
                         str(DEMO_GAMES), "--out", "suite", "--quiet"])
    finally:
        os.chdir(here)
    assert code == 0, (stdout.getvalue(), stderr.getvalue())
    yield work / "suite", work / "results" / "demo" / "capture_times.sqlite", stdout.getvalue()


@pytest.mark.ray
@pytest.mark.slow
def test_the_demo_suite_writes_the_leaderboard_episodes_plot_and_config(demo):
    out, store, r = demo
    assert store.exists()  # the cold store the CLI filled
    policies = allocator_names(("baseline", "planner"), references=True)
    scenarios = ["paper_3x3_c1_1.5", "outnumbered_3x3"]
    board = pd.read_csv(out / "leaderboard.csv")
    assert list(board.columns) == BOARD_COLUMNS
    assert list(zip(board["scenario"], board["policy"])) == [(s, p) for s in scenarios for p in policies]
    assert (board["episodes"] == 2).all()
    assert board[[f"{m}_{s}" for m in MEASURES for s in ("mean", "ci95")]].notna().all().all()
    assert (board["seconds_per_step"] > 0).all()
    assert ((board["eliminated_mean"] >= 0) & (board["eliminated_mean"] <= 1)).all()
    per = pd.read_csv(out / "episodes.csv")
    assert len(per) == len(scenarios) * len(policies) * 2
    assert (out / "leaderboard.png").read_bytes().startswith(b"\x89PNG")
    doc = json.loads((out / "suite.json").read_text())
    assert doc["resolved"]["episodes"] == 2 and doc["resolved"]["seeds"] == [1000, 1001]
    assert doc["resolved"]["policies"] == policies
    assert doc["resolved"]["scenarios"]["outnumbered_3x3"]["env"]["n_defenders"] == 4
    assert doc["resolved"]["scenarios"]["outnumbered_3x3"]["env"]["games"] == DEMO_GAMES  # --games
    assert doc["info"]["warmed_cases"] > 100
    assert "outnumbered_3x3" in r and "leaderboard.csv" in r


@pytest.mark.ray
@pytest.mark.slow
def test_every_policy_sees_the_same_episodes(demo):
    out, _, _ = demo
    per = pd.read_csv(out / "episodes.csv")
    for (scenario, episode), g in per.groupby(["scenario", "episode"]):
        assert g["seed"].nunique() == 1 and g["seed"].iloc[0] == 1000 + episode
        starts = g["intruders_start"].unique()  # the densities each policy observed at the start
        assert len(starts) == 1, (scenario, episode, starts)
        shares = np.array(starts[0].split(), dtype=float)
        assert len(shares) == 3 and abs(shares.sum() - 1) < 1e-6
    # episodes differ from each other (seeded apart)
    assert per[per["episode"] == 0]["intruders_start"].iloc[0] != per[per["episode"] == 1]["intruders_start"].iloc[0]


@pytest.mark.ray
@pytest.mark.slow
def test_the_report_shows_the_leaderboard(demo):
    from farm.report import build_report

    out, _, _ = demo
    page = build_report(out)
    section = page.split("<h2>Leaderboard</h2>", 1)[1].split("<h2>", 1)[0]
    assert "leaderboard chart" in section and "data:image/png;base64" in section
    assert "outnumbered_3x3" in section and "spread_evenly" in section and "±" in section
    assert "suite-demo" in section
    games = page.split("<h2>Game figures</h2>", 1)[1]
    assert "leaderboard.png" not in games  # the chart is shown once, in its section


@pytest.mark.ray
@pytest.mark.slow
def test_a_rerun_gives_the_same_numbers(demo, tmp_path, monkeypatch):
    """One of the demo's scenarios again, every policy, over the store the first run filled,
    each cell's 2 episodes cut into 2 tasks of one (a TASK_COST below a 3 x 3 episode's, as a
    32 x 32 map's cells are cut): the same episodes and leaderboard as the first run, whose
    cells were one task each."""
    out, store, _ = demo
    config = load_suite_config(ROOT / "configs" / "suite_demo.yaml").model_copy(
        update={"store": str(store), "scenarios": ["outnumbered_3x3"], "env": {"games": DEMO_GAMES}})
    monkeypatch.setattr("farm.studies.suite.run.TASK_COST", 1)
    _, info = run_suite(config, tmp_path / "again", episodes=2, show_progress=False)
    assert info["tasks"] == 2 * info["cells"] == 2 * len(config.allocator_names())

    def rows(folder, name, timed):
        df = pd.read_csv(folder / name)
        return df[df["scenario"] == "outnumbered_3x3"].drop(columns=timed).reset_index(drop=True)

    pd.testing.assert_frame_equal(rows(out, "leaderboard.csv", "seconds_per_step"),
                                  rows(tmp_path / "again", "leaderboard.csv", "seconds_per_step"))
    pd.testing.assert_frame_equal(rows(out, "episodes.csv", "predict_seconds"),
                                  rows(tmp_path / "again", "episodes.csv", "predict_seconds"))
    # rerunning into the same folder replaces the suite's files; other results there stay
    (tmp_path / "again" / "notes.txt").write_text("mine")
    run_suite(config.model_copy(update={"policies": ["spread_evenly"]}), tmp_path / "again", episodes=2,
              show_progress=False)
    assert len(pd.read_csv(tmp_path / "again" / "leaderboard.csv")) == 1
    assert (tmp_path / "again" / "notes.txt").read_text() == "mine"


def _untrained_run(run_dir: Path, scenario: str) -> Path:
    """A run folder holding an untrained TD3 model of a scenario's env (its config.yaml names the scenario)."""
    from stable_baselines3 import TD3

    from farm.alloc.envs.defenders import SwarmAllocationEnv

    config = TrainConfig(name="untrained", scenario=scenario)
    run_dir.mkdir(parents=True, exist_ok=True)
    env = SwarmAllocationEnv(config.env, store=run_dir / "unused.sqlite")
    TD3("MlpPolicy", env, policy_kwargs={"net_arch": [8, 8]}, seed=0, device="cpu").save(run_dir / "model.zip")
    env.close()
    write(run_dir / "config.yaml", json.loads(config.model_dump_json()))
    return run_dir


@pytest.mark.ray
@pytest.mark.slow
def test_a_cold_store_without_warming_cannot_deadlock_on_two_cpus(ray_local, demo, tmp_path):
    """Both CPUs held by evaluation tasks whose every engagement misses (games: 3, not in the
    store): the service's game tasks run on the CPUs the waiting tasks lend. Then the same
    suite warmed first gives the same numbers; a TD3 run folder is a policy, a missing one
    is skipped when told so, a run of another env is refused."""
    from farm.service.store import StatsStore

    _, store, _ = demo  # the one service of this Ray serves this store; games 3 are new keys in it
    run = _untrained_run(tmp_path / "run", "outnumbered_3x3")
    config = SuiteConfig(scenarios=["outnumbered_3x3", "paper_3x3_c1_0"], episodes=2, seed=7, store=str(store),
                         policies=[p for p in available_policies() if p in ("spread_evenly", "intercept")],
                         env={"games": 3}, runs={"outnumbered_3x3": str(run), "paper_3x3_c1_0": str(tmp_path / "no")},
                         skip_missing_runs=True)
    settings = SCENARIOS["outnumbered_3x3"].config(games=3).game_settings().key(1, 1).settings_digest()

    def stored() -> int:  # cases of the suite's (games: 3) settings in the store
        s = StatsStore(store, read_only=True)
        try:
            return sum(row[1] == settings for row in s.rows())
        finally:
            s.close()

    assert stored() == 0
    cold, info = run_suite(config, tmp_path / "cold", workers=2, show_progress=False, warm=False)
    assert info["warmed_cases"] == 0 and info["workers"] == 2
    assert stored() > 0  # the misses were computed (and stored) while the evaluations waited
    # the same evaluations of one scenario, its lattice warmed first: the same numbers
    warm, info = run_suite(config.model_copy(update={"scenarios": ["outnumbered_3x3"]}), tmp_path / "warm",
                           workers=2, show_progress=False)
    assert info["warmed_cases"] == 4 * 13  # n_p up to 4 (4 sizes) by n_e up to 96 (13 sizes)
    pd.testing.assert_frame_equal(cold[cold["scenario"] == "outnumbered_3x3"].drop(columns="seconds_per_step"),
                                  warm.drop(columns="seconds_per_step"))
    assert list(cold[cold["scenario"] == "outnumbered_3x3"]["policy"])[-1] == "td3"
    assert "td3" not in set(cold[cold["scenario"] == "paper_3x3_c1_0"]["policy"])
    doc = json.loads((tmp_path / "cold" / "suite.json").read_text())
    assert doc["resolved"]["skipped_runs"] == {"paper_3x3_c1_0": str(tmp_path / "no")}
    assert doc["resolved"]["runs"] == {"outnumbered_3x3": str(run)}
    wrong = config.model_copy(update={"runs": {"paper_3x3_c1_0": str(run)}})
    with pytest.raises(ConfigError, match=r"^runs.paper_3x3_c1_0: .* trained on another env \(n_defenders: 4, "
                                          r"the scenario's 100\)"):
        run_suite(wrong, tmp_path / "wrong", show_progress=False)


def test_evaluate_matchup_in_process_times_predict_and_records_the_start(tmp_path):
    from farm.alloc.allocators import Spec, allocator_entry
    from farm.service.client import CaptureTimeClient

    config = SCENARIOS["paper_3x3_c1_0"].config(games=2)
    client = CaptureTimeClient(config.game_settings(), local_store=tmp_path / "s.sqlite")
    try:
        rows = evaluate_matchup(config, Spec(allocator_entry("stay_at_base")), client, 2, 5)
    finally:
        client.close()
    assert [r["seed"] for r in rows] == [5, 6]
    for r in rows:
        assert r["steps"] == r["length"] and r["predict_seconds"] > 0
        assert len(r["intruders_start"].split()) == 3


def test_the_report_takes_a_bare_leaderboard_and_refuses_a_damaged_one(tmp_path):
    from farm.core.errors import ReportError
    from farm.report import build_report

    board = pd.DataFrame([{"scenario": "s", "policy": "p", "episodes": 1,
                           **{f"{m}_{k}": (0.5 if k == "mean" else np.nan) for m in MEASURES for k in ("mean", "ci95")},
                           "seconds_per_step": 0.001}])
    (tmp_path / "ok").mkdir()
    board.to_csv(tmp_path / "ok" / "leaderboard.csv", index=False)
    section = build_report(tmp_path / "ok").split("<h2>Leaderboard</h2>", 1)[1].split("<h2>", 1)[0]
    assert "0.500" in section and "1.00" in section  # one episode: a mean without a CI; ms per step
    (tmp_path / "bad").mkdir()
    board.drop(columns="eliminated_ci95").to_csv(tmp_path / "bad" / "leaderboard.csv", index=False)
    with pytest.raises(ReportError, match=r"leaderboard.csv: not a leaderboard \(missing eliminated_ci95\)"):
        build_report(tmp_path / "bad")


@pytest.mark.ray
@pytest.mark.slow
def test_an_adversary_axis_adds_every_intruder_policy_and_the_worst_case(demo, tmp_path):
    """`intruders: [drift, fewest_ahead]`: every allocator meets each intruder policy on the same
    episodes; the drift rows are the suite's own (the default intruders) and each (scenario,
    policy)'s worst case is its lowest eliminated mass over the intruder policies."""
    out, store, _ = demo
    config = load_suite_config(ROOT / "configs" / "suite_demo.yaml").model_copy(
        update={"store": str(store), "scenarios": ["outnumbered_3x3"], "policies": ["spread_evenly", "intercept"],
                "env": {"games": DEMO_GAMES}, "intruders": ["drift", "fewest_ahead"]})
    board, _ = run_suite(config, tmp_path / "axis", episodes=2, show_progress=False)
    assert list(zip(board["intruders"], board["policy"])) == [
        ("drift", "spread_evenly"), ("drift", "intercept"), ("fewest_ahead", "spread_evenly"),
        ("fewest_ahead", "intercept")]
    own = pd.read_csv(out / "leaderboard.csv")
    own = own[(own["scenario"] == "outnumbered_3x3") & own["policy"].isin(["spread_evenly", "intercept"])]
    drift = board[board["intruders"] == "drift"]
    np.testing.assert_array_equal(drift["eliminated_mean"].to_numpy(), own["eliminated_mean"].to_numpy())
    for _, g in board.groupby("policy"):
        assert (g["worst_eliminated"] == g["eliminated_mean"].min()).all()
        assert set(g["worst_intruders"]) == {g.loc[g["eliminated_mean"].idxmin(), "intruders"]}
    from farm.studies.suite import format_leaderboard

    assert "worst case" in format_leaderboard(board)
    with pytest.raises(ValidationError, match="unknown intruder policy 'psychic'"):
        SuiteConfig(name="x", intruders=["psychic"])
