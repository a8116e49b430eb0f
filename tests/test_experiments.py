"""`farm experiments`: a grid of TD3 trainings as Ray Tune trials on one capture-time service
(farm/studies/experiments/): the smoke grid on a real 2-CPU Ray with a cold store, resuming, the
same trial twice, the driver SIGKILLed mid-training, a trial of an experiment in object storage
(an S3 server on localhost) SIGKILLed with its local folder deleted (the trials go on from their
checkpoints, to the uninterrupted run's rows), and bad configs in one line."""

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import DEADLINE, bucket_keys, cmdline, holder, kill_session, ray_workers, signal_all, wait_for
from helpers import raises_one_line

from farm.core.errors import ClusterError, ConfigError
from farm.studies.experiments import RESULT

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ROOT / "configs" / "experiments" / "smoke.yaml"


def smoke_config(path: Path, store: Path, **changes) -> Path:
    """configs/experiments/smoke.yaml with its base absolute, the store given and top-level
    fields replaced by `changes` (None drops one), written to path."""
    raw = yaml.safe_load(SMOKE.read_text())
    raw.update(base=str(ROOT / raw["base"]), store=str(store))
    raw.update(changes)
    raw = {k: v for k, v in raw.items() if v is not None}
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def one_line_error(path: Path) -> str:
    from farm.studies.experiments import load_experiment_config, plan

    return raises_one_line(ConfigError, lambda: plan(load_experiment_config(path), str(path)))


@pytest.mark.parametrize("changes, expected", [
    ({"colour": "red"}, "colour: not an experiments field"),
    ({"grid": {"env.colour": [1, 2]}}, "grid: env.colour: not a field of env"),
    ({"grid": {"td3.nope": [1]}}, "grid: td3.nope: not a field of td3"),
    ({"grid": {"seed": [1, 2]}}, "grid: seed: set by the experiment"),
    ({"grid": {"service.store": ["x"]}}, "grid: service.store: set by the experiment"),
    ({"grid": {"env.c_capture": []}}, "grid: env.c_capture: must be a non-empty list"),
    ({"seeds": []}, "seeds: must name at least one seed"),
    ({"seeds": [0, 0]}, "seeds: a seed is named twice"),
    ({"grid": {"td3.learning_rate": [0.001, -1.0]}}, "td3.learning_rate: Input should be greater than 0 (point 1"),
    ({"scenario": "paper_3x3_c1_0"}, "base: give one of `base` (a training config) or `scenario`"),
    ({"base": None}, "base: give `base` (a training config), `scenario` (a suite scenario) or a grid over"),
    ({"base": None, "grid": {"scenario": ["paper_3x3_c1_0", "nowhere"]}}, "unknown scenario 'nowhere'"),
])
def test_a_bad_experiments_config_is_one_line(tmp_path, changes, expected):
    path = smoke_config(tmp_path / "bad.yaml", tmp_path / "store.sqlite", **changes)
    assert expected in one_line_error(path)


def test_the_cli_refuses_a_bad_config_in_one_line(tmp_path, capsys):
    from farm.cli import main

    path = smoke_config(tmp_path / "bad.yaml", tmp_path / "store.sqlite", seeds=[])
    assert main(["experiments", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "seeds: must name at least one seed" in err


def test_the_smoke_plan_is_2_points_by_2_seeds(tmp_path):
    from farm.studies.experiments import load_experiment_config, plan

    p = plan(load_experiment_config(smoke_config(tmp_path / "s.yaml", tmp_path / "store.sqlite")))
    assert [t.key for t in p.trials] == ["p0_s0", "p0_s1", "p1_s0", "p1_s1"]
    assert [t.config["env"]["c_capture"] for t in p.trials] == [0.0, 0.0, 1.5, 1.5]
    assert {t.config["env"]["team_sizes"] for t in p.trials} == {"lattice"}
    assert all(t.config["threads"] == 1 and t.config["service"]["mode"] == "ray" for t in p.trials)


def test_the_display_shows_a_pretraining_trial_by_its_share_of_episodes_then_by_its_steps(tmp_path):
    """What Tune's reports (farm.studies.experiments.tune: report_pretraining, TuneReport) make of
    the bar's text: a trial in its pretraining shows its share of episodes labelled, until its
    first training report or its end."""
    from farm.studies.experiments import load_experiment_config, plan
    from farm.studies.experiments.display import Display

    display = Display(plan(load_experiment_config(smoke_config(tmp_path / "s.yaml", tmp_path / "store.sqlite"))),
                      enabled=False, finished=["p1_s1"])
    display.started("p0_s0")
    display.started("p0_s1")
    display.result("p0_s0", {"phase": "pretrain", "pretrain_episodes": 64, "pretrain_episodes_total": 448,
                             "timesteps_total": 0})
    display.result("p0_s1", {"phase": "pretrain", "pretrain_episodes": 448, "pretrain_episodes_total": 448,
                             "timesteps_total": 0})
    assert display.description() == ("trials: 1/4 done, 2 running, 1 waiting; "
                                     "p0_s0 pretraining 14%, p0_s1 pretraining 100%")
    display.result("p0_s1", {"timesteps": 150, "timesteps_total": 150, "phase": "train"})
    assert display.description() == "trials: 1/4 done, 2 running, 1 waiting; p0_s0 pretraining 14%"
    assert display.steps["p0_s1"] == 150 and display.steps["p0_s0"] == 0
    display.ended("p0_s0", False)
    assert display.description() == "trials: 1/4 done, 1 running, 1 waiting, 1 failed"
    display.close()


def test_a_scenario_is_a_base_and_the_grid_overrides_its_env(tmp_path):
    from farm.alloc.game.scenarios import SCENARIOS
    from farm.studies.experiments import load_experiment_config, plan

    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"name": "sc", "scenario": "outnumbered_3x3", "seeds": [3],
                                    "overrides": {"td3.n_timesteps": 500, "td3.learning_starts": 100},
                                    "grid": {"env.c_capture": [0.5, 1.0], "td3.policy_kwargs.net_arch": [[64, 64]]}}))
    trials = plan(load_experiment_config(path)).trials
    assert [t.key for t in trials] == ["p0_s3", "p1_s3"]
    env = SCENARIOS["outnumbered_3x3"].env
    for t, c in zip(trials, (0.5, 1.0)):
        assert t.config["env"]["c_capture"] == c and t.config["td3"]["n_timesteps"] == 500
        assert t.config["td3"]["policy_kwargs"]["net_arch"] == [64, 64] and t.config["seed"] == 3
        assert all(t.config["env"][k] == v for k, v in env.items() if k != "c_capture")


def test_a_grid_over_scenarios_needs_no_base():
    from farm.alloc.game.scenarios import SCENARIOS, THEATRES
    from farm.studies.experiments import load_experiment_config, plan

    config = load_experiment_config(ROOT / "configs" / "experiments" / "paper.yaml")
    trials = plan(config).trials
    paper = set(SCENARIOS) - set(THEATRES)  # the theatres are the size-free learner's (TD3's MLP is not)
    assert sorted({t.config["scenario"] for t in trials}) == sorted(paper)
    assert [t.seed for t in trials[:3]] == [0, 1, 2] and len(trials) == 3 * len(paper)
    for t in trials:
        env = SCENARIOS[t.config["scenario"]].env
        assert all(t.config["env"][k] == v for k, v in env.items())
        assert t.config["td3"]["n_timesteps"] == 20_000 and t.config["td3"]["policy_kwargs"] == {"net_arch": [400, 300]}


def test_the_cli_refuses_a_folder_of_other_files_in_one_line(tmp_path, capsys):
    from farm.cli import main

    path = smoke_config(tmp_path / "s.yaml", tmp_path / "store.sqlite")
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    assert main(["experiments", str(path), "--out", str(tmp_path / "busy")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("farm: error: --out: ") and "holds no experiment" in err


def test_trials_leave_one_cpu_to_the_games():
    from farm.studies.experiments import trial_cpus

    assert trial_cpus(2, 2) == 0.5  # 2 trials on 2 CPUs: 1 CPU left for the service's game tasks
    assert trial_cpus(2, 1) == 1.0
    assert trial_cpus(64, 64) * 64 <= 63
    with pytest.raises(ClusterError, match="at least 2 CPUs"):
        trial_cpus(1, 1)


def test_a_folder_of_another_experiment_is_refused_before_ray(tmp_path):
    from farm.studies.experiments import ExperimentFolder, load_experiment_config, plan, run_experiment
    from farm.studies.experiments.tables import manifest_trials

    config = load_experiment_config(smoke_config(tmp_path / "s.yaml", tmp_path / "store.sqlite"))
    out = tmp_path / "exp"
    the_plan = plan(config)
    ExperimentFolder(out).write_manifest({"name": the_plan.name, "digest": the_plan.digest,
                                          "config": config.model_dump(mode="json", exclude_unset=True),
                                          "store": the_plan.store, "fields": the_plan.fields,
                                          "trials": manifest_trials(the_plan)})
    other = load_experiment_config(smoke_config(tmp_path / "o.yaml", tmp_path / "store.sqlite", seeds=[0]))
    with pytest.raises(ConfigError, match="holds another experiment") as e:
        run_experiment(other, out, show_progress=False)
    assert "\n" not in str(e.value)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty and holds no experiment"):
        run_experiment(config, tmp_path / "busy", show_progress=False)


def _mtimes(out: Path) -> dict:
    return {p.parent.parent.name: p.stat().st_mtime_ns for p in sorted((out / "trials").glob("*/run/model.zip"))}


@pytest.fixture(scope="module")
def cold(ray_local, tmp_path_factory):
    """The smoke grid (C_capture 0 and 1.5, seeds 0 and 1) on a cold store without warm-up:
    (folder, trials, info, store, config path, experiment folder)."""
    from farm.studies.experiments import load_experiment_config, run_experiment

    tmp = tmp_path_factory.mktemp("cold")
    store = tmp / "store.sqlite"
    path = smoke_config(tmp / "smoke.yaml", store, tracking={"mlflow": {"tracking_uri": str(tmp / "mlflow.db")}})
    out = tmp / "exp"
    trials, _, info = run_experiment(load_experiment_config(path), out, show_progress=False, warm=False)
    return tmp, trials, info, store, path, out


@pytest.mark.ray
@pytest.mark.slow
def test_every_trial_is_an_mlflow_run_whose_metrics_are_its_trials_csv_row(cold):
    """The smoke grid is tracked (tracking.mlflow, an SQLite store): the MLflow logger
    (farm.studies.experiments.tracking.TrialRuns) made one FINISHED run per trial in the
    experiment's MLflow experiment, its params the trial's config, its last metrics the trial's
    row of trials.csv, its steps the training's; the rerun
    (test_smoke_grid_then_a_rerun_trains_nothing) trains nothing and logs no run."""
    from mlflow.tracking import MlflowClient

    tmp, _, _, _, _, out = cold
    client = MlflowClient(tracking_uri=f"sqlite:///{tmp / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("smoke")
    runs = {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}
    trials = pd.read_csv(out / "trials.csv")
    assert sorted(runs) == trials["trial"].tolist() == ["p0_s0", "p0_s1", "p1_s0", "p1_s1"]
    for row in trials.to_dict("records"):
        run = runs[row["trial"]]
        assert run.info.status == "FINISHED" and run.data.tags["farm.experiment"] == "smoke"
        assert run.data.params["spec/trial/seed"] == str(row["seed"])
        assert float(run.data.params["spec/trial/config/env/c_capture"]) == row["env.c_capture"]
        for column in ("learned_eliminated", "receding_horizon_eliminated", "intercept_return", "final_eval_return",
                       "timesteps", "engagements"):
            assert run.data.metrics[column] == pytest.approx(row[column], rel=1e-12), (row["trial"], column)
        steps = [m.step for m in client.get_metric_history(run.info.run_id, "timesteps")]
        assert max(steps) == row["timesteps"] == 300


@pytest.mark.ray
@pytest.mark.slow
def test_two_trials_on_two_cpus_with_a_cold_store(cold):
    """2 trials at once on 2 CPUs, a cold store and no warm-up: every game a trial meets is
    computed while both trials wait, on the CPU the trials leave free (trial_cpus)."""
    _, trials, info, store, _, out = cold
    assert info["workers"] == 2 and info["trial_cpus"] == 0.5 and info["cluster_cpus"] == 2
    assert info["started"] == 4 and info["warmed_cases"] == 0
    assert trials["trial"].tolist() == ["p0_s0", "p0_s1", "p1_s0", "p1_s1"] and (trials["engagements"] > 0).all()
    assert len(pd.read_csv(out / "trials.csv")) == 4 and len(pd.read_csv(out / "summary.csv")) == 2


@pytest.mark.ray
@pytest.mark.slow
def test_smoke_grid_then_a_rerun_trains_nothing(cold):
    """The smoke grid's trials.csv, summary.csv, claims and learning curves; the same command
    again (the lattice warmed this time) trains nothing and gives the same rows. (The same trial
    trained twice gives the same row: the kill tests' finished trials against these.)"""
    from farm.studies.experiments import load_experiment_config, run_experiment

    _, trials, info, _, path, out = cold
    summary = pd.read_csv(out / "summary.csv")
    for policy in ("learned", "stay_at_base", "intercept", "receding_horizon"):
        assert trials[f"{policy}_eliminated"].between(0, 1).all()
    assert summary["seeds"].tolist() == [2, 2] and summary["env.c_capture"].tolist() == [0.0, 1.5]
    assert [p.name for p in info["claims"]] == ["claims.csv", "claims_seeds.csv"] and info["learning_curves"].exists()
    claims = pd.read_csv(out / "claims.csv")  # the pair: points 0 and 1, seeds 0 and 1
    assert [c[:3] for c in claims["claim"]] == ["(a)", "(b)", "(c)"] and "of 2 seeds" in claims["verdict"][0]
    before = _mtimes(out)
    assert len(before) == 4

    trials2, _, info2 = run_experiment(load_experiment_config(path), out, show_progress=False)
    assert _mtimes(out) == before
    assert info2["started"] == 0 and info2["finished_before"] == 4 and info2["tune_finished"] == 4
    pd.testing.assert_frame_equal(trials2, trials)


# ----------------------------------------------------------------------------- kills
# A trial's worker or the driver SIGKILLed mid-training: the trial goes on from its last
# checkpoint and its row equals the cold run's (an uninterrupted run of the same trials: a
# checkpoint's timing changes nothing of a run, so these runs checkpoint every 50 steps for a
# wide window to kill in) but for the timings and resumed_from.


@pytest.fixture(scope="module")
def s3(ray_s3):
    """The S3 bucket `farm` on localhost (conftest.s3_bucket) that the shared Ray (conftest's
    ray_local) was started in, so that its workers have its endpoint and credentials."""
    return ray_s3


def kill_config(tmp: Path, store: Path, pretrain: dict | None = None, **changes) -> Path:
    """The cold run's experiment (point 0 of the smoke grid) checkpointing every 50 steps and,
    as the cold run, without the lattice warm-up (the cold run has stored every case these
    trials meet): its base is tiny.yaml with `service.warm_lattice: false` (and `pretrain`)."""
    base = yaml.safe_load((ROOT / "configs" / "train" / "tiny.yaml").read_text())
    base["service"]["warm_lattice"] = False
    if pretrain is not None:
        base["pretrain"] = pretrain
    (tmp / "tiny.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    return smoke_config(tmp / "kill.yaml", store, grid={"env.c_capture": [0.0]}, base=str(tmp / "tiny.yaml"),
                        overrides={"env.team_sizes": "lattice", "checkpoint_freq": 50}, **changes)


def stopped_when(what: str, ready, stop, resume, run_for: float = 0.02, alive=lambda: True):
    """Let processes run in slices of run_for seconds, stopped (stop()) between them, until
    ready(), checked while they are stopped, returns something true; returns it with the
    processes left stopped. However fast the machine, they have gone on at most one slice past
    the moment ready() first held."""
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        stop()
        value = ready()
        if value:
            return value
        resume()
        if not alive():
            raise AssertionError(f"ended before {what}")
        time.sleep(run_for)
    raise AssertionError(f"no {what} within {DEADLINE} s")


def held_at_checkpoint(run: Path, step: int, alive=lambda: True) -> int:
    """The pid of the Ray worker training run, left SIGSTOPped once run's checkpoint of step
    is on disk. Every Ray worker runs in slices and is stopped while we look, from before the
    trainer starts: a poll of running processes races them (an idle machine trained on from
    the checkpoint of step 150 to the end at 300 before a kill landed; on a loaded CI machine
    finding the trainer took as long), so here the trainer goes at most one slice past it.
    Slices are slow, so they begin at the checkpoint two before (checkpoint_freq 50 steps):
    100 steps are seconds of training, and the poll for it takes 0.05 s."""
    stopped: list[int] = []
    if step > 100:
        wait_for(f"checkpoint of step {step - 100}", lambda: checkpointed(run, step - 100), alive=alive)

    def stop():
        stopped[:] = ray_workers()
        signal_all(stopped, signal.SIGSTOP)

    def trainer_past_the_step():
        pid = holder(run)
        return pid if pid is not None and checkpointed(run, step) else None

    try:
        pid = stopped_when(f"checkpoint of step {step}", trainer_past_the_step, stop,
                           lambda: signal_all(stopped, signal.SIGCONT), alive=alive)
    except BaseException:
        signal_all(stopped, signal.SIGCONT)
        raise
    signal_all([p for p in stopped if p != pid], signal.SIGCONT)
    return pid


def latest_checkpoint_steps(run: Path) -> int | None:
    from farm.alloc.training.runs import latest_checkpoint

    last = latest_checkpoint(run)
    return None if last is None else last[1]


def checkpointed(run: Path, at_least: int) -> bool:
    from farm.alloc.training.runs import latest_checkpoint

    last = latest_checkpoint(run)
    return last is not None and last[1] >= at_least


def assert_rows_equal_cold(trials: pd.DataFrame, cold_trials: pd.DataFrame) -> None:
    from farm.studies.experiments import TIMING_COLUMNS

    keep = [c for c in cold_trials.columns if c not in TIMING_COLUMNS and c != "resumed_from"]
    expected = cold_trials.set_index("trial").loc[trials["trial"]].reset_index()
    pd.testing.assert_frame_equal(trials[keep].reset_index(drop=True), expected[keep])


def run_experiment_killing(config, out: str, kill):
    """run_experiment(config, out) with kill() in a thread beside it (it kills a trial's worker):
    (trials, info, what kill() returned); asserts kill() returned, not failed (the worker was not
    killed, and why)."""
    from farm.studies.experiments import run_experiment

    killed = []

    def killer():
        try:
            killed.append(kill())
        except (AssertionError, ProcessLookupError, OSError) as e:
            killed.append(e)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    trials, _, info = run_experiment(config, out, show_progress=False)
    thread.join(timeout=DEADLINE)
    assert killed and not isinstance(killed[0], Exception), f"the worker was not killed: {killed!r}"
    return trials, info, killed[0]


@pytest.mark.ray
@pytest.mark.slow
def test_a_trial_in_object_storage_killed_with_its_local_folder_goes_on_from_the_bucket(s3, cold, tmp_path):
    """The experiment in an S3 bucket (moto's server on localhost), nothing of it on the local
    disk but the trial's scratch folder: the trial's worker SIGKILLed once it has trained past
    its Tune checkpoint of step 150 (uploaded to the bucket: the local run holds the checkpoint
    of step 200), and its local folder deleted first. FailureConfig restarts the trial, which
    writes its run folder again from the bucket's checkpoint (resumed_from 150, not 200) and
    finishes; its row, read back from the bucket's trials.csv, equals the uninterrupted
    (local) run's, and the scratch folder is gone."""
    import io

    from farm.studies.experiments import load_experiment_config
    from farm.studies.experiments.storage import ExperimentStorage

    _, cold_trials, _, store, _, cold_out = cold
    config = load_experiment_config(kill_config(tmp_path, store, seeds=[0]))
    out = "s3://farm/kill"
    run = ExperimentStorage(out).run_dir("p0_s0")
    local_files = sorted(tmp_path.iterdir())

    def kill_past_the_checkpoint() -> int:
        """The checkpoint the local run held when its worker was killed."""
        pid = held_at_checkpoint(run, 200)
        local = latest_checkpoint_steps(run)
        shutil.rmtree(run)
        os.kill(pid, signal.SIGKILL)
        return local

    trials, info, local = run_experiment_killing(config, out, kill_past_the_checkpoint)
    assert 200 <= local < 300
    assert trials["resumed_from"].tolist() == [150]
    assert_rows_equal_cold(trials, cold_trials)
    from_bucket = pd.read_csv(io.BytesIO(s3.get_object(Bucket="farm", Key="kill/trials.csv")["Body"].read()))
    assert_rows_equal_cold(from_bucket, pd.read_csv(cold_out / "trials.csv"))  # both read back from csv
    keys = bucket_keys(s3, prefix="kill/")
    assert {"kill/experiment.json", "kill/summary.csv", "kill/trials/p0_s0/result.json",
            "kill/trials/p0_s0/run/model.zip", "kill/trials/p0_s0/run/eval_table.csv"} <= set(keys)
    assert any(k.startswith("kill/tune/p0_s0/checkpoint_") and k.endswith("rl_model_state_150_steps.pkl") for k in keys)
    assert not any(k.startswith("kill/trials/p0_s0/run/checkpoints/") for k in keys)  # the state is Tune's checkpoints'
    assert info["written"][0] == "s3://farm/kill/trials.csv"
    assert sorted(tmp_path.iterdir()) == local_files and not run.exists()


@pytest.mark.ray
@pytest.mark.slow
def test_a_trial_in_object_storage_killed_in_its_pretraining_goes_on_after_the_bucket_s_iteration(s3, cold, tmp_path):
    """The kill test above, in the pretraining (DAgger from intercept, 3 iterations): the trial's
    worker SIGKILLed, its local folder deleted first, once the bucket holds the Tune checkpoint
    of pretraining iteration 1 (farm.studies.experiments.tune.PretrainReport), so that iteration
    0's checkpoint is whole and reported (iteration 1's may be in its upload, or not yet reported
    to the driver: Tune restores a trial from the last checkpoint the driver has). The restarted
    trial writes its run folder again from the bucket and goes on after iteration 0 or 1
    (metrics.json's pretrain_resumed_after), not from the start; its pretraining and training
    equal the same config's uninterrupted run in process, number for number."""
    from farm.alloc.training import TrainConfig, train
    from farm.studies.experiments import load_experiment_config, plan
    from farm.studies.experiments.storage import ExperimentStorage

    _, _, _, store, _, _ = cold
    pretraining = {"expert": "intercept", "iterations": 3, "episodes": 8, "expert_share": 0.5, "epochs": 5,
                   "batch_size": 16, "episodes_per_task": 2}
    config = load_experiment_config(kill_config(tmp_path, store, seeds=[0], pretrain=pretraining))
    out = "s3://farm/kill-pretrain"
    run = ExperimentStorage(out).run_dir("p0_s0")

    def bucket_iteration():
        keys = bucket_keys(s3, prefix="kill-pretrain/tune/p0_s0/")
        found = [int(k.rsplit("iteration_", 1)[1].split(".")[0]) for k in keys if "/run/pretrain/iteration_" in k]
        return max(found) if found else None

    def kill_in_the_pretraining() -> int:
        """The newest iteration in the bucket when the trial's worker was killed (every Ray worker
        stopped while we look, as in held_at_checkpoint)."""
        stopped: list[int] = []

        def stop():
            stopped[:] = ray_workers()
            signal_all(stopped, signal.SIGSTOP)

        try:
            stopped_when("pretraining iteration 1's checkpoint in the bucket", lambda: (bucket_iteration() or 0) >= 1,
                         stop, lambda: signal_all(stopped, signal.SIGCONT), run_for=0.05)
            iteration = bucket_iteration()  # its uploader, the trial's worker, is stopped
            trainers = [pid for pid in stopped if cmdline(pid).startswith(b"ray::ImplicitFunc")]
            assert len(trainers) == 1, trainers
            shutil.rmtree(run)
            os.kill(trainers[0], signal.SIGKILL)
            return iteration
        finally:
            signal_all(stopped, signal.SIGCONT)

    trials, _, iteration = run_experiment_killing(config, out, kill_in_the_pretraining)
    assert iteration == 1  # killed with an iteration still to label
    metrics = json.loads(s3.get_object(Bucket="farm", Key="kill-pretrain/trials/p0_s0/run/metrics.json")["Body"].read())
    assert metrics["pretrain_resumed_after"] in (0, 1)  # not from the start
    trial = plan(config).trials[0].config
    whole = train(TrainConfig(**{**trial, "service": {**trial["service"], "mode": "local"}}), tmp_path / "whole",
                  show_progress=False)
    for name in ("pretrain_states", "pretrain_loss", "pretrained_eval_mean_return", "final_eval_mean_return",
                 "best_eval_mean_return", "timesteps"):
        assert metrics[name] == whole[name], name
    assert trials["trial"].tolist() == ["p0_s0"] and not run.exists()


@pytest.mark.ray
@pytest.mark.slow
def test_a_driver_killed_mid_experiment_then_rerun_trains_no_trial_twice(cold, tmp_path):
    """`farm experiments --address` (the module's Ray, 2 trials at once) SIGKILLed, with its
    trials' workers, once p0_s0 has finished while p0_s1, held stopped since its checkpoint of
    step 150, has not; the same experiment again (run_experiment, in this process on the same Ray:
    no second driver to start) leaves the finished trial untouched, resumes the other from its
    checkpoint, and both rows equal the uninterrupted run's. (A driver killed with the local Ray
    it started is tests/test_cluster_cli.py's sweep case: Tune's restore is the same either way,
    and joining the running Ray spares two Ray starts.)"""
    import ray

    from farm.studies.experiments import load_experiment_config, plan, run_experiment, trials_table

    _, cold_trials, _, store, _, _ = cold
    mlflow_db = tmp_path / "mlflow.db"
    path = kill_config(tmp_path, store, tracking={"mlflow": {"tracking_uri": str(mlflow_db)}})
    out = tmp_path / "exp"
    command = [sys.executable, "-m", "farm.cli", "experiments", str(path), "--out", str(out), "--quiet",
               "--address", ray.get_runtime_context().gcs_address]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("RAY_ADDRESS", None)
    runs = {key: out / "trials" / key / "run" for key in ("p0_s0", "p0_s1")}
    finished, unfinished = "p0_s0", "p0_s1"

    with open(tmp_path / "driver.log", "w") as log:
        driver = subprocess.Popen(command, env=env, start_new_session=True, stdout=log, stderr=subprocess.STDOUT)
        running = lambda: driver.poll() is None  # noqa: E731
        try:
            held_at_checkpoint(runs[unfinished], 150, alive=running)
            wait_for(f"{finished} finished", lambda: (out / "trials" / finished / RESULT).exists(), alive=running)
        finally:
            kill_session(driver)
            signal_all([p for p in (holder(run) for run in runs.values()) if p], signal.SIGKILL)  # its trials
    wait_for("the killed workers gone", lambda: all(holder(run) is None for run in runs.values()))
    result = out / "trials" / finished / RESULT
    before = (result.read_bytes(), result.stat().st_mtime_ns, (runs[finished] / "model.zip").stat().st_mtime_ns)
    assert not (runs[unfinished] / "metrics.json").exists()

    run_experiment(load_experiment_config(path), out, source=str(path), show_progress=False)
    assert (result.read_bytes(), result.stat().st_mtime_ns, (runs[finished] / "model.zip").stat().st_mtime_ns) == before
    resumed_from = json.loads((runs[unfinished] / "metrics.json").read_text())["resumed_from"]
    assert 150 <= resumed_from < 300
    trials = trials_table(plan(load_experiment_config(path)), out)  # trials.csv's rows, from result.json
    assert trials["trial"].tolist() == ["p0_s0", "p0_s1"] and (out / "trials.csv").exists()
    assert_rows_equal_cold(trials, cold_trials)
    # tracked: the resumed trial went on logging into the MLflow run it had before the kill
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{mlflow_db}")
    runs = client.search_runs([client.get_experiment_by_name("smoke").experiment_id])
    assert sorted(r.info.run_name for r in runs) == ["p0_s0", "p0_s1"]
    again = next(r for r in runs if r.info.run_name == unfinished)
    steps = sorted(m.step for m in client.get_metric_history(again.info.run_id, "timesteps_total"))
    assert again.info.status == "FINISHED" and steps[0] < resumed_from and steps[-1] == 300
