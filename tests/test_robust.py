"""`farm robust`: the config's refusals, the library oracle's loop (each iteration's meta-game the
LP's solution of the kept payoffs, each response a best reply, each mixture's value against the
exact search that of its members' searches, a rerun that plays or searches nothing twice), the
trained oracle keeping the seed of its best response that gains most,
and a driver killed mid-iteration whose rerun trains no trial twice and ends with the populations
and payoffs of an uninterrupted run."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import cmdline, holder, kill_session, ray_workers, signal_all, wait_for
from pydantic import ValidationError

from farm.alloc.allocators import make_allocator
from farm.alloc.evaluation.rollout import play
from farm.alloc.intruders.exact_search import exact_response
from farm.core.config import first_line
from farm.core.matrix_game import solve
from farm.service.client import CaptureTimeClient
from farm.studies.robust import RobustConfig, run_robust
from farm.studies.robust.config import FloorParams
from farm.studies.robust.exact import deterministic, searchable
from farm.studies.robust.loop import digest, payoff_matrix
from farm.studies.robust.payoffs import PayoffStore, payoff_key

ROOT = Path(__file__).resolve().parent.parent
GAMES = 8  # games per capture-time case: a cold store fills in seconds


@pytest.mark.parametrize("settings, words", [
    ({"scenario": "nowhere"}, "scenario: unknown scenario 'nowhere'"),
    ({"allocators": []}, "allocators: the population needs one member at least"),
    ({"intruders": ["telepathy"]}, "intruders: unknown intruder policy 'telepathy'"),
    ({"allocators": [{"name": "intercept", "depth": 2}]}, "allocators[0]: a member is a name or"),
    ({"library": {"allocators": ["nobody"]}}, "library.allocators: unknown allocator 'nobody'"),
    ({"payoffs": {"measure": "style"}}, "payoffs.measure"),
    ({"env": {"information": "psychic"}}, "information"),
    ({"iterations": -1}, "iterations"),
    ({"responses": 0}, "responses"),
    ({"intruders_oracle": "psychic"}, "intruders_oracle"),
    ({"scenario": "outnumbered_5x5", "intruders_oracle": "search"},
     "intruders_oracle: search: the search tree of outnumbered_5x5 does not fit"),
    ({"intruders_oracle": "search", "allocators": [{"name": "mixture", "options": {"members": ["intercept"]}}]},
     "intruders_oracle: search models deterministic allocators; mixture"),
    ({"floor": {"allocator": "minimax"}}, "floor: 'minimax' is not one of the starting allocators"),
    ({"floor": {"intruders": "fewest_ahead"}, "intruders": ["drift"]},
     "floor: 'fewest_ahead' is not one of the starting intruders"),
    ({"floor": {"margin": -0.1}}, "floor.margin"),
    ({"floor": {"reference": "x"}}, "floor.reference"),
    # options and run folders checked with the registries' own checks when the config is read
    ({"allocators": [{"name": "receding_horizon", "options": {"horizon": 0}}]}, "allocators[0]: "),
    ({"allocators": [{"name": "intercept", "options": {"depth": 2}}]},
     "allocators[0]: intercept has no option 'depth'"),
    ({"allocators": [{"name": "mixture", "options": {"members": []}}]}, "allocators[0].members: a non-empty list"),
    ({"allocators": [{"name": "mixture", "options": {"members": ["intercept", {"policy": "mmr", "options": {"x": 1}}],
                                                      "weights": [1, 1]}}]},
     "allocators[0].members[1]: mmr has no option 'x'"),
    ({"allocators": [{"name": "mixture", "options": {"members": ["intercept"], "weights": [True]}}]},
     "allocators[0].weights"),
    ({"intruders": [{"name": "learned"}]}, "intruders[0]: a learned member needs its run folder"),
    ({"intruders": [{"name": "learned", "options": {"run": "/nowhere"}}]}, "intruders[0]: /nowhere holds no trained"),
    ({"allocators": [{"name": "ppo", "options": {"run": "/nowhere"}}]}, "allocators[0]: /nowhere holds no trained"),
    ({"intruders": [{"name": "drift", "options": {"speed": 2}}]}, "intruders[0]: drift has no option 'speed'"),
])
def test_a_bad_robust_config_is_one_line_naming_its_field(settings, words):
    with pytest.raises(ValidationError) as e:
        RobustConfig(**{"name": "x", "scenario": "outnumbered_3x3", **settings})
    assert words in first_line(e.value) and "\n" not in first_line(e.value)


def test_a_run_folder_of_the_other_side_is_refused_in_one_line(tmp_path):
    import zipfile

    run = tmp_path / "run"
    run.mkdir()
    with zipfile.ZipFile(run / "model.zip", "w") as z:
        z.writestr("data", "{}")
    (run / "config.yaml").write_text("side: intruders\n")
    with pytest.raises(ValidationError) as e:
        RobustConfig(name="x", scenario="outnumbered_3x3", allocators=[{"name": "ppo", "options": {"run": str(run)}}])
    assert f"allocators[0]: {run} is not a training of the defenders (its config.yaml says side: intruders)" \
        == first_line(e.value)
    (run / "model.zip").write_bytes(b"damaged")
    with pytest.raises(ValidationError) as e:
        RobustConfig(name="x", scenario="outnumbered_3x3",
                     intruders=[{"name": "learned", "options": {"run": str(run)}}])
    assert "holds no trained model" in first_line(e.value)


def test_every_robust_config_of_the_project_loads():
    from farm.studies.robust import load_robust_config

    paths = sorted((ROOT / "configs" / "robust").glob("*.yaml"))
    assert len(paths) >= 4
    for path in paths:
        assert load_robust_config(path).name


def library_config(tmp_path, iterations):
    return RobustConfig(name="lib", scenario="outnumbered_3x3", env={"games": GAMES}, iterations=iterations,
                        allocators=["spread_evenly"], intruders=["drift"], oracle="library",
                        library={"allocators": ["intercept", "transport"], "intruders": ["fewest_ahead", "split_away"]},
                        payoffs={"episodes": 3}, distill=None, store=str(tmp_path / "store.sqlite"))


@pytest.mark.ray
def test_the_library_oracles_loop_and_its_resumed_rerun(ray_local, tmp_path):
    out = tmp_path / "out"
    first, info = run_robust(library_config(tmp_path, 1), out, show_progress=False)
    assert len(first) == 1 and info["iterations_before"] == 0
    iterations, again = run_robust(library_config(tmp_path, 2), out, show_progress=False)
    assert again["iterations_before"] == 1 and iterations[0].to_dict() == first[0].to_dict()
    config, store = library_config(tmp_path, 2), PayoffStore(out / "payoffs")
    files_before = len(list((out / "payoffs").iterdir()))
    for it in iterations:
        M = payoff_matrix(store, config, it.allocators, it.intruders)
        solution = solve(M)
        assert it.value == pytest.approx(solution.value, abs=1e-9) and it.nash_conv >= 0
        # the library's responses are best replies to the mixtures, among the candidates and members
        for side, opponents, mix in (("allocators", it.intruders, it.column), ("intruders", it.allocators, it.row)):
            options = it.allocators + config.candidates("allocators") if side == "allocators" else \
                it.intruders + config.candidates("intruders")
            rows = payoff_matrix(store, config, options, opponents) if side == "allocators" else \
                payoff_matrix(store, config, opponents, options).T
            worth = rows @ np.asarray(mix)
            best = worth.max() if side == "allocators" else worth.min()
            chosen = worth[[m.key() for m in options].index(it.responses[side].key())]
            assert chosen == pytest.approx(best)
    # each iteration's allocators' mixture against the intruders' exact best response: its support's
    # searches redone here, in this process, weighted by the mixture; no intruder policy does better
    env, p = config.alloc_config(), config.payoffs
    client = CaptureTimeClient(env.game_settings(), local_store=tmp_path / "store.sqlite")
    searched = {}
    for it in iterations:
        value = 0.0
        for a, w in zip(it.allocators, it.row):
            if w > 0:
                key = json.dumps(a.key(), sort_keys=True)
                if key not in searched:
                    policy = make_allocator(a.name, env, client, **a.options)
                    searched[key] = np.array([exact_response(env, policy, client, p.seed + k).summary["eliminated"]
                                                  for k in range(p.episodes)])
                    for b in it.intruders:  # episode by episode, no intruder policy below the search
                        played = store.get(payoff_key(env, a, b, p.episodes, p.seed))["eliminated"]
                        assert np.all(searched[key] <= played + 1e-12)
                value += w * searched[key].mean()
        assert it.exact["value"] == pytest.approx(value, abs=1e-12)
        assert it.exact["gain_intruders"] == pytest.approx(it.value - value, abs=1e-12)
        assert it.exact["gain_intruders"] >= it.gains["intruders"] - 1e-12
        assert it.exact["nash_conv"] >= it.nash_conv - 1e-12
    assert info["exact_searched"] + again["exact_searched"] == len(searched)
    # a finished run again: nothing played or searched, the same files
    _, third = run_robust(config, out, show_progress=False)
    assert third["pairs_played"] == 0 and third["exact_searched"] == 0
    assert len(list((out / "payoffs").iterdir())) == files_before
    table = pd.read_csv(out / "nash_conv.csv")
    assert list(table["iteration"]) == list(range(len(iterations)))
    assert list(table["exact_value"]) == [it.exact["value"] for it in iterations]
    mixture = yaml.safe_load((out / "mixture.yaml").read_text())
    assert mixture["allocator"]["name"] == "mixture" and sum(mixture["allocator"]["options"]["weights"]) == \
        pytest.approx(1.0)
    with pytest.raises(Exception, match="holds a robust run of another config"):
        run_robust(config.model_copy(update={"payoffs": config.payoffs.model_copy(update={"episodes": 4})}), out,
                   show_progress=False)
    # damaged state of a finished run: a kept payoff of its final populations is played again (not a
    # traceback), and a robust.json cut short is moved aside and its iterations computed again
    from farm.studies.robust.loop import final_populations

    a, b = (population[0] for population in final_populations(iterations))
    store.path(payoff_key(env, a, b, p.episodes, p.seed, out)).write_text('{"values": {}, "sha')
    redone, fourth = run_robust(config, out, show_progress=False)
    assert fourth["pairs_played"] == 1 and [it.to_dict() for it in redone] == [it.to_dict() for it in iterations]
    state = (out / "robust.json").read_text()
    (out / "robust.json").write_text(state[: len(state) // 2])
    redone, fifth = run_robust(config, out, show_progress=False)
    assert fifth["pairs_played"] == 0 and [it.to_dict() for it in redone] == [it.to_dict() for it in iterations]
    assert (out / "damaged" / "robust.json").read_text() == state[: len(state) // 2]


@pytest.mark.ray
def test_the_floored_loop_keeps_the_drift_case_and_answers_with_the_floors_price(ray_local, tmp_path):
    robust = {"name": "minimax", "options": {"robustness": 1.0}, "label": "minimax_r1"}
    config = RobustConfig(name="floor", scenario="outnumbered_3x3", env={"games": GAMES}, iterations=3,
                          allocators=["receding_horizon"], intruders=["drift"], oracle="library",
                          library={"allocators": ["intercept", robust], "intruders": ["fewest_ahead", "split_away"]},
                          floor={"margin": 0.02}, payoffs={"episodes": 3}, distill=None, exact="never",
                          store=str(tmp_path / "store.sqlite"))
    out = tmp_path / "out"
    iterations, _ = run_robust(config, out, show_progress=False)
    store = PayoffStore(out / "payoffs")
    for it in iterations:
        M = payoff_matrix(store, config, it.allocators, it.intruders)
        target = float(M[0, 0]) - 0.02  # receding_horizon against drift, less the margin
        solution = solve(M, (0, target))
        assert it.row == pytest.approx(solution.row.tolist(), abs=1e-9) and it.value == pytest.approx(solution.value)
        assert it.floor == pytest.approx({"target": target, "held": float(solution.row @ M[:, 0]),
                                          "price": solution.price})
        assert it.floor["held"] >= target - 1e-9 and it.value <= solve(M).value + 1e-9
        # the defenders' response: the best worth among the candidates and members, the floor's price on drift
        options = it.allocators + [c for c in config.candidates("allocators") if c not in it.allocators]
        worth = solution.row_worth(payoff_matrix(store, config, options, it.intruders))
        chosen = [m.key() for m in options].index(it.responses["allocators"].key())
        assert worth[chosen] == pytest.approx(worth.max())
        assert it.gains["defenders"] == pytest.approx(float(worth[chosen]) - solution.value, abs=1e-12)
    assert any(it.floor["price"] > 0 for it in iterations)  # the floor binds: minimax at 1 keeps less under drift
    table = pd.read_csv(out / "nash_conv.csv")
    assert list(table["floor_held"]) == pytest.approx([it.floor["held"] for it in iterations])
    mixture = yaml.safe_load((out / "mixture.yaml").read_text())
    weights = np.asarray(mixture["allocator"]["options"]["weights"])
    assert mixture["floor"]["held"] >= mixture["floor"]["target"] - 1e-9
    final = pd.read_csv(out / "payoffs.csv", index_col=0)
    assert float(weights @ final["drift"].to_numpy()) == pytest.approx(mixture["floor"]["held"])
    with pytest.raises(Exception, match="holds a robust run of another config"):
        run_robust(config.model_copy(update={"floor": None}), out, show_progress=False)


@pytest.mark.ray
def test_the_search_oracles_loop_answers_each_mixture_with_intruders_modelling_it(ray_local, tmp_path):
    config = library_config(tmp_path, 2).model_copy(update={"intruders_oracle": "search"})
    out = tmp_path / "out"
    iterations, info = run_robust(config, out, show_progress=False)
    env, p = config.alloc_config(), config.payoffs
    store = PayoffStore(out / "payoffs")
    client = CaptureTimeClient(env.game_settings(), local_store=tmp_path / "store.sqlite")
    for k, it in enumerate(iterations):
        response = it.responses["intruders"]
        support = [(a, w) for a, w in zip(it.allocators, it.row) if w > 0]
        assert response.name == "search" and response.label == f"br{k}"
        assert response.options == {"allocators": [a.spec() for a, _ in support],
                                     "weights": [w for _, w in support], "objective": "eliminated"}
        # its payoffs (Ray tasks) are its play here, in this process; its gain is the exact one here, where
        # each member's first move tells it apart, and no intruder policy of the population gains more
        searcher = env.model_copy(update={"intruders": "search", "intruder_options": response.options})
        worth = 0.0
        for a, w in support:
            here = play(searcher, make_allocator(a.name, env, client, **a.options), client, p.episodes, p.seed)
            stored = store.get(payoff_key(env, a, response, p.episodes, p.seed))["eliminated"]
            np.testing.assert_array_equal(stored, [e.summary["eliminated"] for e in here])
            worth += w * np.mean(stored)
        assert it.gains["intruders"] == pytest.approx(it.value - worth, abs=1e-12)
        assert it.gains["intruders"] == pytest.approx(it.exact["gain_intruders"], abs=1e-12)
        M = payoff_matrix(store, config, it.allocators, it.intruders)
        assert it.gains["intruders"] >= float(it.value - (np.asarray(it.row) @ M).min()) - 1e-12
    assert iterations[1].intruders[-1] == iterations[0].responses["intruders"]
    for it in iterations:  # a response the population holds already (by name and options) is not added again
        keys = [json.dumps(m.key(), sort_keys=True) for m in it.intruders]
        assert len(set(keys)) == len(keys)
    _, again = run_robust(config, out, show_progress=False)
    assert again["pairs_played"] == 0 and info["pairs_played"] > 0
    with pytest.raises(Exception, match="holds a robust run of another config"):
        run_robust(library_config(tmp_path, 2), out, show_progress=False)


def test_a_response_the_population_holds_already_whatever_its_label_joins_it_once():
    from farm.studies.robust.loop import Iteration, final_populations
    from farm.studies.robust.members import Member

    model = {"allocators": [{"policy": "minimax", "options": {}}], "weights": [1.0], "objective": "eliminated"}
    held, again = Member("intruders", "search", model, "br0"), Member("intruders", "search", dict(model), "br1")
    new = Member("allocators", "ppo", {"run": "r1"}, "br1")
    it = Iteration([Member("allocators", "minimax")], [Member("intruders", "drift"), held], [1.0], [0.5, 0.5], 0.5,
                   {"allocators": new, "intruders": again}, {"defenders": 0.0, "intruders": 0.0}, 0.0)
    allocators, intruders = final_populations([it])
    assert allocators == [Member("allocators", "minimax"), new] and intruders == [Member("intruders", "drift"), held]


def test_the_exact_valuation_is_only_on_maps_whose_search_tree_fits_and_of_deterministic_allocators():
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.studies.robust.members import member_of

    assert searchable(SCENARIOS["outnumbered_3x3"].config(), 20, 2000)
    assert not searchable(SCENARIOS["outnumbered_5x5"].config(), 20, 2000)
    members = ["intercept", "spread_evenly"]
    assert deterministic(member_of("allocators", "intercept", "allocators"))
    assert deterministic(member_of("allocators", {"name": "mixture", "options": {"members": members, "draw": "mean"}},
                                   "allocators"))
    for draw in ("episode", "step"):
        assert not deterministic(member_of("allocators", {"name": "mixture", "options": {"members": members,
                                                                                          "draw": draw}}, "allocators"))


TINY = {"algo": "ppo", "ppo.n_timesteps": 256, "ppo.n_steps": 32, "ppo.batch_size": 64, "ppo.n_epochs": 2,
        "n_envs": 2, "eval.freq": 128, "eval.episodes": 2, "checkpoint_freq": 64}


def trained_config(tmp_path, **changes) -> Path:
    """Both sides trained (the defenders pretrained from intercept) on outnumbered_3x3, one iteration,
    top-level fields replaced by changes; the config's path."""
    config = {"name": "trained", "scenario": "outnumbered_3x3", "env": {"games": GAMES}, "iterations": 1,
              "allocators": ["spread_evenly", "intercept"], "intruders": ["drift", "fewest_ahead"],
              "payoffs": {"episodes": 3}, "distill": None, "exact": "never", "store": str(tmp_path / "store.sqlite"),
              "training": {"defenders": {**TINY, "pretrain": {"expert": "intercept", "iterations": 1, "episodes": 2}},
                           "intruders": TINY}, **changes}
    path = tmp_path / "robust.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def trained_run(ray_local, tmp_path_factory):
    """The trained oracle's loop run uninterrupted, two seeds a side (four trials, two at a time):
    (config path, results folder, its iteration)."""
    from farm.studies.robust import load_robust_config

    root = tmp_path_factory.mktemp("trained")
    path = trained_config(root, responses=2, seed=1)
    (it,), _ = run_robust(load_robust_config(path), root / "whole", show_progress=False)
    return path, root / "whole", it


@pytest.mark.ray
@pytest.mark.slow
def test_the_trained_oracle_keeps_the_seed_gaining_most(trained_run):
    from farm.studies.experiments.storage import ExperimentStorage
    from farm.studies.robust import load_robust_config
    from farm.studies.robust.members import Member
    from farm.studies.robust.oracles import response_seeds

    path, out, it = trained_run
    config = load_robust_config(path)
    seeds = response_seeds(config, 0)
    assert seeds == [1000, 1100]  # seed 1: the second seed gains most on both sides
    trials = sorted(p.name for p in (out / "iterations" / "0" / "trials").iterdir() if (p / "run").is_dir())
    assert trials == sorted(f"p{p}_s{s}" for p in (0, 1) for s in seeds)
    store, storage = PayoffStore(out / "payoffs"), ExperimentStorage(out / "iterations" / "0")
    for point, side, key in ((0, "allocators", "defenders"), (1, "intruders", "intruders")):
        kept = it.responses[side]
        candidates = [Member(side, kept.name, {"run": str(storage.run_dir(f"p{point}_s{s}"))}) for s in seeds]
        if side == "allocators":
            gains = payoff_matrix(store, config, candidates, it.intruders) @ np.asarray(it.column) - it.value
        else:
            gains = it.value - np.asarray(it.row) @ payoff_matrix(store, config, it.allocators, candidates)
        assert it.gains[f"{key}_candidates"] == pytest.approx(gains.tolist(), abs=1e-12)
        assert kept.options == candidates[int(np.argmax(gains))].options
        assert it.gains[key] == pytest.approx(float(gains.max()), abs=1e-12)


@pytest.mark.ray
@pytest.mark.slow
def test_a_robust_folder_moved_elsewhere_resumes_on_its_own_models(trained_run, tmp_path):
    import shutil

    from farm.core.errors import ConfigError
    from farm.studies.robust import load_robust_config

    path, out, it = trained_run
    moved = tmp_path / "elsewhere" / "run"
    shutil.copytree(out, moved)
    saved = json.loads((moved / "robust.json").read_text())
    runs = [m["options"]["run"] for m in saved["iterations"][0]["responses"].values()]
    assert runs and all(not Path(r).is_absolute() and r.startswith("iterations/0/trials/") for r in runs)
    (again,), info = run_robust(load_robust_config(path), moved, show_progress=False)
    assert info["pairs_played"] == 0  # every pair's payoff found under its key, the runs keyed relative to the folder
    assert again.to_dict(moved) == it.to_dict(out)
    assert all(Path(m.options["run"]).is_relative_to(moved) for m in again.responses.values())
    kept = again.responses["intruders"]
    (Path(kept.options["run"]) / "model.zip").write_bytes(b"damaged")
    with pytest.raises(ConfigError) as e:
        run_robust(load_robust_config(path), moved, show_progress=False)
    assert str(e.value) == (f"{moved / 'robust.json'}: iteration 0: {kept.shown()}: {kept.options['run']} holds no "
                            f"trained model (model.zip); train it with farm train")


def test_a_payoff_file_under_another_pairs_name_is_no_payoff_of_that_pair(tmp_path, capsys):
    store = PayoffStore(tmp_path / "payoffs")
    a = {m: [0.25, 0.5] for m in ("eliminated", "breached", "return")}
    b = {m: [0.75, 1.0] for m in a}
    store.put("a" * 32, a)
    store.put("b" * 32, b)
    pa, pb = store.path("a" * 32), store.path("b" * 32)
    da, db = pa.read_bytes(), pb.read_bytes()
    pa.write_bytes(db)
    pb.write_bytes(da)  # swapped: each file's values and checksum intact, under the other pair's name
    assert store.get("a" * 32) is None and store.get("b" * 32) is None
    assert capsys.readouterr().err.count("is damaged (ValueError); played again") == 2


@pytest.mark.parametrize("oracle, intruders_oracle, trained", [
    ("trained", "oracle", ["allocators", "intruders"]), ("trained", "trained", ["allocators", "intruders"]),
    ("trained", "search", ["allocators"]), ("trained", "library", ["allocators"]),
    ("library", "trained", ["intruders"]), ("library", "oracle", []), ("library", "search", [])])
def test_an_iterations_experiment_holds_a_point_a_trained_side(oracle, intruders_oracle, trained):
    from farm.core.matrix_game import solve
    from farm.studies.robust.oracles import iteration_experiment

    config = RobustConfig(name="x", scenario="outnumbered_3x3", oracle=oracle, intruders_oracle=intruders_oracle,
                          allocators=["intercept"], intruders=["drift", "fewest_ahead"])
    assert config.trained_sides() == trained
    spelled_out = config.model_copy(update={"intruders_oracle": config.oracle_of("intruders")})
    assert (digest(spelled_out) == digest(config.model_copy(update={"intruders_oracle": "oracle"}))) == \
        (intruders_oracle in ("oracle", oracle))  # naming the defenders' oracle again is the same experiment
    assert digest(config) != digest(config.model_copy(update={"floor": FloorParams()}))
    if not trained:
        return
    experiment = iteration_experiment(config, 0, config.population("allocators"), config.population("intruders"),
                                      solve(np.array([[0.7, 0.4]])))
    sides = ["intruders" if point.get("side") == "intruders" else "allocators" for point in experiment.points]
    assert sides == trained
    for point in experiment.points:  # each side trains against the other's mixture
        if point.get("side") == "intruders":
            assert point["opponent.options"]["members"] == [{"policy": "intercept", "options": {}}]
        else:
            assert point["env.intruder_options"]["weights"] == pytest.approx([0.0, 1.0])


def test_under_a_floor_the_defenders_train_against_the_mixture_with_the_floors_price_on_drift():
    from farm.studies.robust.oracles import iteration_experiment

    config = RobustConfig(name="x", scenario="outnumbered_3x3", allocators=["receding_horizon", "intercept"],
                          intruders=["drift", "fewest_ahead"], floor={"margin": 0.05})
    allocators, intruders = config.population("allocators"), config.population("intruders")
    M = np.array([[0.8, 0.0], [0.7, 0.5]])
    assert config.floor_of(M, allocators, intruders) == (0, pytest.approx(0.75))
    solution = solve(M, config.floor_of(M, allocators, intruders))  # price 5 on drift (tests/test_matrix_game.py)
    defenders, attackers = iteration_experiment(config, 0, allocators, intruders, solution).points
    assert defenders["env.intruder_options"]["weights"] == pytest.approx([5 / 6, 1 / 6])
    assert attackers["opponent.options"]["weights"] == pytest.approx([0.5, 0.5])


@pytest.mark.ray
@pytest.mark.slow
def test_an_oracle_a_side_the_defenders_library_against_trained_intruders(ray_local, tmp_path):
    from farm.studies.robust import load_robust_config

    config = RobustConfig(**{**load_robust_config(trained_config(tmp_path)).model_dump(), "iterations": 1,
                             "oracle": "library", "intruders_oracle": "trained",
                             "library": {"allocators": ["transport"], "intruders": ["split_away"]}})
    assert config.trained_sides() == ["intruders"] and config.oracle_of("allocators") == "library"
    out = tmp_path / "out"
    (it,), _ = run_robust(config, out, show_progress=False)
    trials = sorted(p.name for p in (out / "iterations" / "0" / "trials").iterdir() if (p / "run").is_dir())
    assert trials == ["p0_s0"]  # the intruders' training only, as point 0
    store = PayoffStore(out / "payoffs")
    defenders, intruders = it.responses["allocators"], it.responses["intruders"]
    assert intruders.name == "learned" and Path(intruders.options["run"]).is_dir()
    assert "/trials/p0_s0/" in intruders.options["run"]
    options = it.allocators + config.candidates("allocators")
    worth = payoff_matrix(store, config, options, it.intruders) @ np.asarray(it.column)
    assert defenders == options[int(np.argmax(worth))]  # the library's answer, not a trained one
    assert it.gains["defenders"] == pytest.approx(float(worth.max()) - it.value, abs=1e-12)
    assert it.gains["intruders"] == pytest.approx(
        it.value - float(np.asarray(it.row) @ payoff_matrix(store, config, it.allocators, [intruders])[:, 0]),
        abs=1e-12)


@pytest.mark.ray
@pytest.mark.slow
def test_a_driver_killed_mid_iteration_then_rerun_trains_no_trial_twice(trained_run, tmp_path):
    """`farm robust --address` (the shared Ray) SIGKILLed, with its trials' workers, once the first
    of the iteration's four trials has finished; the same run again (run_robust, in this process
    on the same Ray: no second driver to start) trains none of the finished ones and plays no pair
    again, and ends with the uninterrupted run's populations and payoffs."""
    import ray

    from farm.studies.robust import load_robust_config

    path, whole, it = trained_run
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "farm.cli", "robust", str(path), "--out", str(out), "--quiet",
               "--address", ray.get_runtime_context().gcs_address]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("RAY_ADDRESS", None)
    trials = out / "iterations" / "0" / "trials"
    driver = subprocess.Popen(command, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)

    def trainers():
        return [pid for pid in ray_workers() if cmdline(pid).startswith(b"ray::ImplicitFunc")]

    try:
        wait_for("a finished trial", lambda: any(trials.glob("*/result.json")), alive=lambda: driver.poll() is None)
    finally:
        kill_session(driver)
        signal_all(trainers(), signal.SIGKILL)  # the trials' workers, which would write on
    wait_for("the killed trials' workers gone", lambda: not trainers() and holder(out) is None)
    done = sorted(trials.glob("*/result.json"))
    assert 0 < len(done) < 4 and not (out / "nash_conv.csv").exists(), "the driver was not killed mid-iteration"
    state = out / "robust.json"  # written as each iteration ends
    assert not state.exists() or json.loads(state.read_text())["iterations"] == []
    kept = sorted((out / "payoffs").iterdir())
    assert kept  # the starting populations' pairs, played before the trainings
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in done + kept}
    run_robust(load_robust_config(path), out, show_progress=False)
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in done + kept} == before  # never trained or played again
    assert len(list(trials.glob("*/result.json"))) == 4
    (killed,) = json.loads((out / "robust.json").read_text())["iterations"]
    for side in ("allocators", "intruders"):
        assert [m["label"] or m["name"] for m in killed[side]] == [m.label or m.name for m in getattr(it, side)]
        response = killed["responses"][side]["options"]["run"]  # the same trial's model joins
        assert Path(response) == Path(it.responses[side].options["run"]).relative_to(whole)  # kept relative to out
    assert killed["row"] == pytest.approx(it.row, abs=1e-12) and killed["value"] == pytest.approx(it.value, abs=1e-12)
    for key in ("defenders", "intruders"):
        assert killed["gains"][key] == pytest.approx(it.gains[key], abs=1e-12)
    np.testing.assert_array_equal(pd.read_csv(out / "payoffs.csv", index_col=0).to_numpy(),
                                  pd.read_csv(whole / "payoffs.csv", index_col=0).to_numpy())


@pytest.mark.parametrize("settings, line", [
    ({"training": {"defenders": {"ppo.n_timesteps": -1}}},
     "training.defenders: ppo.n_timesteps: Input should be greater than or equal to 1"),
    ({"training": {"intruders": {"ppo.n_timestepz": 5}}}, "training.intruders: ppo.n_timestepz: not a field of ppo"),
    ({"training": {"defenders": {"ppo.n_timesteps": float("nan")}}}, "training.defenders: ppo.n_timesteps: must be"),
    ({"training": {"defenders": {"side": "intruders"}}}, "training.defenders: side: the robust loop sets it"),
    ({"distill": {"algo": "dqn"}}, "distill: algo: Input should be 'td3', 'ppo' or 'sac'"),
])
def test_the_trainings_settings_are_refused_before_ray_starts_or_a_pair_is_played(settings, line, tmp_path):
    import yaml
    from conftest import farm_main

    config = tmp_path / "robust.yaml"
    config.write_text(yaml.safe_dump({"name": "x", "scenario": "outnumbered_3x3", "allocators": ["intercept"],
                                      "intruders": ["drift"], **settings}))
    status, out, err = farm_main("robust", str(config), "--out", str(tmp_path / "out"))
    assert status == 2 and err.startswith("farm: error: ") and line in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()  # nothing written, no pair played


@pytest.mark.parametrize("held, command", [("exploit", "robust"), ("robust", "exploit")])
def test_a_folder_holding_the_other_kind_of_run_is_refused_before_any_work(held, command, tmp_path):
    import yaml
    from conftest import farm_main

    out = tmp_path / "out"
    (out / "payoffs").mkdir(parents=True)
    (out / f"{held}.json").write_text("{}")  # the other kind's state file, as a run of it leaves it
    before = sorted(p.name for p in out.iterdir())
    config = tmp_path / "c.yaml"
    if command == "robust":
        config.write_text(yaml.safe_dump({"name": "x", "scenario": "outnumbered_3x3", "allocators": ["intercept"],
                                          "intruders": ["drift"], "oracle": "library", "distill": None}))
    else:
        config.write_text(yaml.safe_dump({"name": "x", "scenarios": ["outnumbered_3x3"], "allocators": ["intercept"],
                                          "learned": None}))
    status, _, err = farm_main(command, str(config), "--out", str(out))
    article = {"exploit": "an", "robust": "a"}
    assert (status, err) == (2, f"farm: error: --out: {out} holds {article[held]} {held} run, not {article[command]} "
                                f"{command} one; choose another folder\n")
    assert sorted(p.name for p in out.iterdir()) == before  # nothing written into it


@pytest.mark.parametrize("damage", ["cut short", "a digit edited", "no checksum", "another kind's"])
def test_a_damaged_state_file_is_moved_aside_in_one_line_and_computed_again(damage, tmp_path, capsys):
    from farm.studies.robust.payoffs import read_state, write_state

    path = tmp_path / "robust.json"
    values = {"name": "x", "digest": "0123", "iterations": [{"value": 0.625}]}
    write_state(path, "robust", values)
    assert read_state(path, "robust") == values
    text = path.read_text()
    path.write_text({"cut short": text[:40], "a digit edited": text.replace("0.625", "0.626"),
                     "no checksum": json.dumps(values), "another kind's": text}[damage])
    assert read_state(path, "exploit" if damage == "another kind's" else "robust") is None
    assert not path.exists() and (tmp_path / "damaged" / "robust.json").exists()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path} is damaged" in err and "computed again" in err
