"""A tiny TD3 run end to end: train, resume, load, evaluate against the baselines."""

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from conftest import farm_main
from helpers import farm_process as farm

REPO = Path(__file__).resolve().parents[1]


def farm_here(*args):
    """`farm ARGS` through farm.cli.main in this process (no interpreter start, about 5 s with
    torch): returncode, stdout, stderr. The first train and eval here stay real subprocesses."""
    status, out, err = farm_main(*args)
    return SimpleNamespace(returncode=status, stdout=out, stderr=err)


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory):
    d = tmp_path_factory.mktemp("train")
    text = (REPO / "configs/train/tiny.yaml").read_text().replace(
        "results/capture_times_tiny.sqlite", str(d / "store.sqlite"))
    path = d / "tiny.yaml"
    path.write_text(text)
    return path


@pytest.mark.slow
def test_tiny_training_saves_a_model_that_loads_and_evaluates(tiny_config, tmp_path):
    run = tmp_path / "run"
    r = farm("train", tiny_config, "--out", run, "--quiet")
    assert r.returncode == 0, r.stderr[-2000:]
    for name in ("model.zip", "config.yaml", "metrics.json", "evaluations.npz"):
        assert (run / name).exists(), name
    assert list((run / "tb").rglob("events.out.tfevents.*")), "no TensorBoard log"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["timesteps"] == 300 and metrics["final_eval_mean_return"] is not None
    assert 0 < metrics["update_seconds"] < metrics["wall_seconds"] and 0 < metrics["outside_update_share"] < 1

    from stable_baselines3 import TD3

    model = TD3.load(run / "model.zip", device="cpu")
    assert [m.out_features for m in model.actor.mu if hasattr(m, "out_features")] == [400, 300, 49]
    assert [m.out_features for m in model.critic.qf0 if hasattr(m, "out_features")] == [400, 300, 1]

    import yaml

    saved = yaml.safe_load((run / "config.yaml").read_text())
    del saved["log_interval"]  # a run saved before a field existed resumes at the field's default
    (run / "config.yaml").write_text(yaml.safe_dump(saved))
    r = farm_here("train", tiny_config, "--out", run, "--quiet", "--resume", "--timesteps", 450)
    assert r.returncode == 0, r.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["timesteps"] == 450 and metrics["resumed_from"] == 300

    r = farm("eval", run, "--episodes", 3)
    assert r.returncode == 0, r.stderr[-2000:]
    table = pd.read_csv(run / "eval_table.csv")
    assert list(table["policy"]) == ["td3", "stay_at_base", "greedy_nearest", "spread_evenly", "intercept", "mmr",
                                     "receding_horizon", "transport"]
    assert {"return_mean", "return_ci95", "eliminated_mean", "breached_mean", "length_mean"} <= set(table.columns)
    assert (table["episodes"] == 3).all()
    assert len(list(run.glob("density_*.png"))) == 8
    assert (run / "training_curve.png").exists()

    r = farm_here("eval", run, "--episodes", 2, "--fidelity", "games")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "return, games minus service:" in r.stdout
    diffs = pd.read_csv(run / "fidelity_differences.csv")
    assert len(diffs) > 0 and diffs["game_frac_tau"].between(0, 1).all()
    # fresh games, numbered from the service's 3 games up, the same ones for every policy
    assert (diffs.groupby(["policy", "n_pursuers", "n_evaders"])["game"].min() == 3).all()
    assert set(pd.read_csv(run / "eval_table_games.csv")["policy"]) == set(table["policy"])

    # a run folder the tables cannot be written into is refused before any episode (issue 28)
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    if subprocess.run(["chattr", "+i", str(run)], capture_output=True).returncode == 0:
        try:
            r = farm_here("eval", run, "--episodes", 2)
        finally:
            subprocess.run(["chattr", "-i", str(run)], check=True)
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr[-2000:]
        assert f"run_dir: {run} cannot be written (it is read-only)" in r.stderr
        assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before

    r = farm_here("report", run, "-o", tmp_path / "report.html")
    assert r.returncode == 0, r.stderr[-2000:]
    page = (tmp_path / "report.html").read_text()
    assert "share outside updates" in page and "density_td3.png" in page and "td3" in page


def test_train_bad_config_and_refusals(tiny_config, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nenv: {grid_size: 1}\n")
    r = farm_here("train", bad, "--out", tmp_path / "r")
    assert r.returncode == 2 and "env.grid_size: Input should be greater than or equal to 2" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    bad.write_text("name: x\ntd3: {learning_rate: -1}\n")
    r = farm_here("train", bad, "--out", tmp_path / "r")
    assert r.returncode == 2 and "td3.learning_rate" in r.stderr
    r = farm_here("eval", tmp_path / "nothing")
    assert r.returncode == 2 and "not a training run" in r.stderr
    r = farm_here("train", tiny_config, "--out", tmp_path / "r2", "--resume")
    assert r.returncode == 2 and "holds no run to resume" in r.stderr
