"""What the second bad-input probe found (issue 28), each a one-line error naming the field,
before any work: a positions JSON with a boolean or an unknown key, `--debug` after the
subcommand, a metrics port out of range, gym.make with a bad setting, set_state with densities
that are not densities, cells_at with a negative frame, a client asked after close(). No Ray."""

import json

import gymnasium
import numpy as np
import pytest

import farm.alloc as _registers_the_gymnasium_ids  # noqa: F401
from farm.alloc import AllocConfig, SwarmAllocationEnv
from conftest import farm_main as farm_cli, train_tiny_run
from helpers import farm_refusal
from farm.core.errors import ConfigError
from farm.service import CaptureTimeClient, GameSettings
from workers import Case, InputError, run_games

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)


@pytest.mark.parametrize("data, fragment", [
    ({"pursuers": [[1, 2], [True, 3]], "evaders": [[5, 5]]}, "--positions: pursuers: [true, 3] is not a pair"),
    ({"pursuers": [[1, 2]], "evaders": [[5, 5]], "speed": 2}, "--positions: unknown key 'speed'"),
    ({"pursuers": [[1, 2]], "evaders": [[5, float("nan")]]}, "--positions: evaders: [5, NaN] is not a pair"),
    ({"pursuers": [[1, 2, 3]], "evaders": [[5, 5]]}, "--positions: pursuers: expected a list of [x, y] pairs"),
    ({"pursuers": [1, 2], "evaders": [[5, 5]]}, "--positions: pursuers: expected a list of [x, y] pairs"),
])
def test_a_positions_json_with_a_boolean_or_an_unknown_key_is_refused(tmp_path, data, fragment):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    status, out, err = farm_cli("game", "--positions", path)
    farm_refusal(status, err, fragment)
    assert out == ""  # no game was played


def test_a_good_positions_json_still_plays(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"pursuers": [[1, 2], [3.5, 4]], "evaders": [[5, 5]]}))
    status, out, err = farm_cli("game", "--positions", path)
    assert status == 0 and "2 pursuer(s)" in out, err


def test_debug_is_taken_after_the_subcommand_too():
    status, out, err = farm_cli("game", "--n-pursuers", 2, "--debug")
    assert status == 0 and "2 pursuer(s)" in out, err
    with pytest.raises(Exception, match="--n-pursuers: must be a whole number >= 1"):  # --debug: the traceback
        farm_cli("game", "--n-pursuers", 0, "--debug")


@pytest.mark.parametrize("port", [-5, 0, 70000])
def test_a_metrics_port_out_of_range_is_refused_before_ray_starts(tmp_path, port):
    status, out, err = farm_cli("sweep", "configs/smoke.yaml", "--out", tmp_path / "s", "--metrics-port", port)
    farm_refusal(status, err, "--metrics-port: must be a TCP port from 1 to 65535", str(port))
    assert not (tmp_path / "s").exists()
    from farm.runtime.cluster import ray_cluster

    with pytest.raises(ConfigError, match="^metrics_port: must be a TCP port"):
        with ray_cluster(metrics_port=port):
            pass


@pytest.mark.parametrize("env_id", ["farm/SwarmAllocation-v0", "farm/outnumbered_5x5-v0"])
@pytest.mark.parametrize("setting, fragment", [({"grid_size": 1}, "grid_size: "), ({"colour": 1}, "colour: "),
                                               ({"c_capture": float("nan")}, "c_capture: must be a finite number"),
                                               ({"n_defenders": True}, "n_defenders: must not be a bool")])
def test_gym_make_with_a_bad_setting_is_one_config_error_naming_it(env_id, setting, fragment):
    with pytest.raises(ConfigError) as err:
        gymnasium.make(env_id, **setting)
    message = str(err.value)
    assert message.startswith(fragment) and "\n" not in message and "pydantic" not in message, message
    with pytest.raises(ConfigError, match=f"^{fragment.split(':')[0]}: "):
        gymnasium.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **setting)


@pytest.mark.parametrize("side, value", [("D", np.nan), ("I", -0.1), ("D", np.inf)])
def test_set_state_refuses_densities_that_are_not_densities_and_leaves_the_env(side, value):
    env = SwarmAllocationEnv(AllocConfig(**SMALL), client=object())
    env.reset(seed=1)
    state = env.get_state()
    before = env.get_state()
    state[side] = state[side].copy()
    state[side][4] = value
    with pytest.raises(ConfigError, match=f"^set_state: the state's densities {side} must be finite numbers >= 0"):
        env.set_state(state)
    np.testing.assert_array_equal(env.D, before["D"])
    np.testing.assert_array_equal(env.I, before["I"])


def test_cells_at_refuses_a_negative_frame_or_a_game_out_of_range():
    res = run_games(Case(n_pursuers=3, n_evaders=1, t_max=5.0), 0, 0, 2, record=True)
    cells, agents = res.cells_at(10**6, 1)  # past the end: the last recorded frame
    assert len(agents) >= 3
    for frame, game, fragment in [(-1, 0, "frame must be a whole number >= 0"), (0, 2, "game must be a whole number"),
                                  (0, -1, "game must be a whole number"), (1.5, 0, "frame must be")]:
        with pytest.raises(InputError, match=f"^cells_at: {fragment}"):
            res.cells_at(frame, game)


def test_a_client_asked_after_close_says_so_in_one_line(tmp_path):
    client = CaptureTimeClient(GameSettings.of(games=3, t_max=15.0), local_store=tmp_path / "s.sqlite")
    client.get(1, 1)
    shared = client.with_settings(client.settings)
    client.close()
    client.close()  # twice is allowed
    for ask in (lambda: client.get(1, 1), lambda: client.get(2, 1), lambda: client.get_many([(1, 1)]),
                lambda: client.warm([(1, 1)]), lambda: shared.get(1, 2)):
        with pytest.raises(InputError, match="^CaptureTimeClient: closed"):
            ask()


# ----- settings that cannot train, statistics that contradict their games ------------------

TINY = "name: x\nservice: {mode: local}\n"


@pytest.mark.parametrize("section, fragment", [
    ("td3: {n_timesteps: 300, learning_starts: 300}", "td3.learning_starts: 300 steps of random actions"),
    ("algo: sac\nsac: {n_timesteps: 300, learning_starts: 1000}", "sac.learning_starts: 1000 steps"),
    ("td3: {n_timesteps: 300, learning_starts: 100, buffer_size: 1, batch_size: 1}",
     "td3: buffer_size: a replay buffer of 1"),
    ("td3: {n_timesteps: 300, learning_starts: 100, buffer_size: 50, batch_size: 64}",
     "td3: batch_size: minibatches of 64"),
    ("td3: {n_timesteps: 300, learning_starts: 100, buffer_size: 3, batch_size: 2}\nn_envs: 4",
     "td3.buffer_size: 3 transitions over n_envs = 4"),
])
def test_training_settings_under_which_nothing_is_learned_are_refused_before_any_work(tmp_path, section, fragment):
    path = tmp_path / "train.yaml"
    path.write_text(TINY + section + "\n")
    status, out, err = farm_cli("train", path, "--out", tmp_path / "run")
    farm_refusal(status, err, fragment)
    assert not (tmp_path / "run").exists()


def test_timesteps_on_the_command_line_below_learning_starts_is_refused(tmp_path):
    status, out, err = farm_cli("train", "configs/train/tiny.yaml", "--timesteps", 100, "--out", tmp_path / "run")
    farm_refusal(status, err, "--timesteps: 100 steps, but td3.learning_starts is 100")
    assert not (tmp_path / "run").exists()


def test_a_window_tau_longer_than_the_games_is_refused_where_statistics_are_made(tmp_path):
    from workers import run_case

    case = Case(n_pursuers=2, n_evaders=1, t_max=10.0, tau=50.0)
    with pytest.raises(InputError, match=r"^tau: the statistics window \(50 s\) is longer than the games"):
        run_case(case, 2, 0)
    with pytest.raises(InputError, match="^tau: the statistics window"):
        GameSettings.of(games=4, t_max=10.0, tau=50.0).key(2, 1)
    assert run_games(case, 0, 0, 1).n_games == 1  # the game itself does not need tau
    table = tmp_path / "t.yaml"
    table.write_text("name: t\nn_pursuers: [1, 2]\nn_evaders: [1]\nsettings: {games: 4, t_max: 10, tau: 50}\n")
    status, out, err = farm_cli("table", table, "--store", tmp_path / "s.sqlite")
    farm_refusal(status, err, "tau: the statistics window (50 s)")
    assert not (tmp_path / "s.sqlite").exists()
    sweep = tmp_path / "w.yaml"
    sweep.write_text("name: w\nbase: {n_evaders: 1, t_max: 10}\nvary: {grid: {n_pursuers: [1, 2], tau: [5, 20]}}\n")
    status, out, err = farm_cli("sweep", sweep, "--out", tmp_path / "w", "--no-ray")
    farm_refusal(status, err, "vary: point 1 (n_pursuers=1, tau=20): tau: the statistics window (20 s)")
    assert not (tmp_path / "w").exists()


def test_a_random_integer_range_without_a_whole_number_is_refused_and_draws_stay_inside(tmp_path):
    from farm.games.sweep import load_sweep_config

    path = tmp_path / "r.yaml"
    path.write_text("name: r\nbase: {n_evaders: 1}\nvary: {random: {n: 3, ranges: {n_pursuers: [1.2, 1.7]}}}\n")
    status, out, err = farm_cli("sweep", path, "--out", tmp_path / "r", "--no-ray")
    farm_refusal(status, err, "n_pursuers: [1.2, 1.7] holds no whole number")
    path.write_text("name: r\nbase: {n_evaders: 1}\nvary: {random: {n: 200, ranges: {n_pursuers: [1.5, 3.5]}}}\n")
    drawn = {p.changes["n_pursuers"] for p in load_sweep_config(path).points()}
    assert drawn == {2, 3}  # every whole number inside, none outside


@pytest.mark.parametrize("kind, text", [
    ("table", "name: t\nn_pursuers: [1]\nn_evaders: [1]\nstore: ''\n"),
    ("train", "name: x\nservice: {mode: local, store: ''}\n"),
    ("suite", "name: s\nstore: ''\n"),
    ("experiments", "name: e\nbase: configs/train/tiny.yaml\nseeds: [0]\nstore: ''\n"),
])
def test_an_empty_store_path_is_refused_not_read_as_the_default(tmp_path, kind, text):
    path = tmp_path / f"{kind}.yaml"
    path.write_text(text)
    argv = {"table": ("table", path), "train": ("train", path, "--out", tmp_path / "run"),
            "suite": ("suite", path, "--out", tmp_path / "suite"),
            "experiments": ("experiments", path, "--out", tmp_path / "exp")}[kind]
    status, out, err = farm_cli(*argv)
    farm_refusal(status, err, "store: String should have at least 1 character")
    status, out, err = farm_cli("table", "configs/table_small.yaml", "--store", "")
    farm_refusal(status, err, "--store: an empty value")


# ----- a run folder whose files were damaged or edited -------------------------------------

@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny trained and evaluated run (TD3 on 3x3, 120 steps, service in process)."""
    run = train_tiny_run(tmp_path_factory.mktemp("probe_run"), "eval: {freq: 60, episodes: 2}\ncheckpoint_freq: 60\n")
    status, out, err = farm_cli("eval", run, "--episodes", 2, "--references", "none")
    assert status == 0, err
    return run


@pytest.mark.parametrize("damage, fragment", [
    (b"garbage,,\x00\n", "not farm eval's per-step table (no column 'policy')"),
    (b"\x00\xff\xfe", "unreadable per-step evaluation"),
    (b"policy,episode,step,coverage,engaged_cells,defenders_per_engaged\ntd3,0,x,1.0,3.0,3.3\n",
     "column 'step' holds values that are not numbers"),
])
def test_claims_on_a_damaged_eval_steps_is_one_line_naming_the_file(run, tmp_path, damage, fragment):
    import shutil

    runs = tmp_path / "runs"
    for name, c in (("c0", "0.0"), ("c15", "1.5")):
        shutil.copytree(run, runs / name)
        text = (runs / name / "config.yaml").read_text().replace("c_capture: 1.5", f"c_capture: {c}")
        (runs / name / "config.yaml").write_text(text)
    (runs / "c0" / "eval_steps.csv").write_bytes(damage)
    status, out, err = farm_cli("claims", runs, "--c0", "c0", "--c15", "c15")
    farm_refusal(status, err, "c0/eval_steps.csv: ", fragment, "rerun farm eval")
    assert not (runs / "claims.csv").exists()


def test_an_edited_run_config_whose_grid_no_longer_fits_the_model_is_one_line(run, tmp_path):
    import shutil

    edited = tmp_path / "edited"
    shutil.copytree(run, edited)
    (edited / "config.yaml").write_text((edited / "config.yaml").read_text().replace("grid_size: 3", "grid_size: 4"))
    before = {p.name: p.read_bytes() for p in edited.iterdir() if p.is_file()}
    status, out, err = farm_cli("eval", edited, "--episodes", 1, "--references", "none")
    farm_refusal(status, err, "run_dir: ", "config.yaml does not fit its model", "3x3", "4x4")
    status, out, err = farm_cli("train", edited / "config.yaml", "--out", edited, "--resume")
    farm_refusal(status, err, "--resume: ", "trained on another map than config.yaml's 4x4")
    after = {p.name: p.read_bytes() for p in edited.iterdir() if p.is_file()}
    assert {k: v for k, v in after.items() if k in before} == before  # nothing already computed is changed
