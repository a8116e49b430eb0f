"""What the second bad-input probe found (issue 28), each a one-line error naming the field,
before any work: a positions JSON with a boolean or an unknown key, `--debug` after the
subcommand, a metrics port out of range, gym.make with a bad setting, set_state with densities
that are not densities, cells_at with a negative frame, a client asked after close(). No Ray."""

import contextlib
import io
import json

import gymnasium
import numpy as np
import pytest

import farm.alloc as _registers_the_gymnasium_ids  # noqa: F401
from farm.alloc import AllocConfig, SwarmAllocationEnv
from farm.cli import main
from farm.core.errors import ConfigError
from farm.service import CaptureTimeClient, ServiceSettings
from workers import Case, InputError, run_games

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)


def farm_cli(*argv):
    """farm.cli.main in this process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


def one_line(status, err, *fragments):
    assert status == 2, err
    line = err.strip()
    assert line.startswith("farm: error: ") and "\n" not in line and "Traceback" not in line, line
    for f in fragments:
        assert f in line, line


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
    one_line(status, err, fragment)
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
    one_line(status, err, "--metrics-port: must be a TCP port from 1 to 65535", str(port))
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
    client = CaptureTimeClient(ServiceSettings.of(games=3, t_max=15.0), local_store=tmp_path / "s.sqlite")
    client.get(1, 1)
    shared = client.with_settings(client.settings)
    client.close()
    client.close()  # twice is allowed
    for ask in (lambda: client.get(1, 1), lambda: client.get(2, 1), lambda: client.get_many([(1, 1)]),
                lambda: client.warm([(1, 1)]), lambda: shared.get(1, 2)):
        with pytest.raises(InputError, match="^CaptureTimeClient: closed"):
            ask()
