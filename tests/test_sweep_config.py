"""Sweep configs: resolution of points, and one-line errors for bad ones."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from farm.core.config import ConfigError
from farm.games.sweep import load_sweep_config

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path, text):
    p = tmp_path / "sweep.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_shipped_configs_load():
    sizes = load_sweep_config(REPO / "configs/team_sizes.yaml").points()
    assert len(sizes) == 20 * 10 * 2
    assert {(p.case.n_pursuers, p.case.n_evaders) for p in sizes} == {(a, b) for a in range(1, 21)
                                                                      for b in range(1, 11)}
    assert ({(p.case.pursuer_policy, p.case.evader_policy) for p in sizes}
            == {("area_min", "centroid"), ("pure_pursuit", "target")})
    paper = load_sweep_config(REPO / "configs/paper_tables.yaml").points()
    assert [(p.case.n_pursuers, p.case.pursuer_policy, p.case.evader_policy) for p in paper] == [
        (1, "pure_pursuit", "target"), (3, "pure_pursuit", "target"), (5, "pure_pursuit", "target"),
        (1, "area_min", "constant_area"), (3, "area_min", "centroid"), (5, "area_min", "centroid"),
    ]
    radius = load_sweep_config(REPO / "configs/capture_radius.yaml").points()
    assert [p.case.capture_radius for p in radius][:3] == [0.05, 0.1, 0.15]
    for name in ("smoke", "paper_tables", "team_sizes", "capture_radius"):
        assert load_sweep_config(REPO / f"configs/{name}.yaml").sweep_id()


def test_grid_zip_random_product(tmp_path):
    cfg = load_sweep_config(write(tmp_path, """
        name: t
        games_per_point: 10
        vary:
          grid: {n_pursuers: [1, 2, 3]}
          zip: {capture_radius: [0.2, 0.3], dt: [0.01, 0.02]}
          random: {n: 4, ranges: {tau: [2.0, 6.0], n_evaders: [1, 3]}}
    """))
    points = cfg.points()
    assert len(points) == 3 * 2 * 4
    assert {(p.case.capture_radius, p.case.dt) for p in points} == {(0.2, 0.01), (0.3, 0.02)}
    taus = {p.case.tau for p in points}
    assert len(taus) == 4 and all(2.0 <= t <= 6.0 for t in taus)
    assert {p.case.n_evaders for p in points} <= {1, 2, 3}
    assert [p.changes for p in cfg.points()] == [p.changes for p in points]  # random draws are seeded
    assert points[0].shards()[-1][2] == 10


def test_sweep_id_changes_with_what_changes_numbers(tmp_path):
    base = "base: {n_pursuers: 3, n_evaders: 1"
    a = load_sweep_config(write(tmp_path, f"name: t\nseed: 1\n{base}}}\n")).sweep_id()
    b = load_sweep_config(write(tmp_path, f"name: t\nseed: 2\n{base}}}\n")).sweep_id()
    c = load_sweep_config(write(tmp_path, f"name: t\nseed: 1\n{base}, dt: 0.02}}\n")).sweep_id()
    d = load_sweep_config(write(tmp_path, f"name: u\nseed: 1\n{base}}}\n")).sweep_id()
    assert len({a, b, c}) == 3 and a == d


BAD = [
    ("name: t\ncolour: red\n", "colour: Extra inputs are not permitted"),
    ("name: t\nbase: {n_pursuers: 0, n_evaders: 1}\n", "base: n_pursuers: must be a whole number >= 1, got 0"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, dt: -1}\n", "base: dt: must be positive and finite, got -1.0"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, pursuer_policy: chase}\n",
     "base: pursuer_policy: unknown policy 'chase'"),
    ("name: t\nbase: {speed: 2}\n", "base: speed: not a game setting (choose from n_pursuers, n_evaders"),
    ("name: t\nvary: {grid: {speed: [1, 2]}}\n", "'speed' cannot vary"),
    ("name: t\nvary: {zip: {dt: [0.1, 0.2], tau: [1]}}\n", "zip: lists must have the same length"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1}\nvary: {grid: {evader_policy: [centroid, hide]}}\n",
     "vary: point 1 (evader_policy='hide'): evader_policy: unknown policy 'hide'"),
    ("name: t\nbase: {n_pursuers: 2}\nvary: {grid: {n_evaders: [1, -1]}}\n", "vary: point 1 (n_evaders=-1)"),
    ("name: t\nvary: {random: {n: 3, ranges: {dt: [0.2, 0.1]}}}\n", "dt: range must be [low, high]"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, pursuer_speed: 0}\n",
     "base: pursuer_speed: must be positive and finite, got 0.0"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, evader_speed: .inf}\n",
     "base: evader_speed: must be positive and finite, got inf"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, exit_point: [1]}\n", "base: exit_point.1: Field required"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, exit_point: [.nan, 5]}\n",
     "base: exit_point: must be a finite point (x, y)"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1}\nvary: {grid: {evader_speed: [1, -1]}}\n",
     "vary: point 1 (evader_speed=-1): evader_speed: must be positive and finite, got -1.0"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1}\nvary: {grid: {exit_point: [[0, 5], [0, .inf]]}}\n",
     "vary: point 1 (exit_point=[0, inf]): exit_point: must be a finite point"),
    ("name: t\nvary: {random: {n: 2, ranges: {exit_point: [0, 5]}}}\n", "'exit_point' cannot be drawn at random"),
    ("name: t\ngames_per_point: many\n", "games_per_point: Input should be a valid integer"),
    ("name: t\n", "base: n_pursuers: Field required"),
    ("name: t\nbase: {n_pursuers: 2, n_evaders: 1, engine_version: '1.0'}\n",
     "base: engine_version: not a game setting"),
    ("name: 'a b'\n", "name: String should match pattern"),
    ("- just\n- a list\n", "must be a mapping"),
    ("name: [unclosed\n", "not valid YAML (line"),
]


@pytest.mark.parametrize("text,message", BAD)
def test_bad_config_one_line(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_sweep_config(path)
    assert message in str(err.value), str(err.value)
    assert "\n" not in str(err.value) and str(err.value).startswith(str(path))


@pytest.mark.slow
def test_cli_bad_config_is_one_line_and_keeps_results(tmp_path):
    good = write(tmp_path, "name: t\ngames_per_point: 4\nbase: {n_pursuers: 2, n_evaders: 1, t_max: 10}\n")
    out = tmp_path / "out"
    def run(*a):
        return subprocess.run([sys.executable, "-m", "farm.cli", *map(str, a)], capture_output=True, text=True,
                              timeout=300)

    r = run("sweep", good, "--out", out, "--no-ray", "--quiet")
    assert r.returncode == 0, r.stderr
    before = {p.name: p.read_bytes() for p in (out / "shards").iterdir()}
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: t\nbase: {n_pursuers: 3, n_evaders: 1}\n")
    for args, message in [
        (("sweep", bad, "--out", out, "--no-ray"), "holds sweep"),
        (("sweep", tmp_path / "nope.yaml"), "no such config file"),
        (("sweep", good, "--workers", "0"), "--workers: must be a whole number >= 1, got 0"),
        (("sweep", good, "--out", good), "exists and is not a folder"),
    ]:
        r = run(*args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert message in r.stderr and "Traceback" not in r.stderr
    assert {p.name: p.read_bytes() for p in (out / "shards").iterdir()} == before


def test_nan_target_is_rejected_before_anything_runs(tmp_path):
    with pytest.raises(ConfigError, match="target: must be a finite point"):
        load_sweep_config(write(tmp_path, "name: t\nbase: {n_pursuers: 1, n_evaders: 1, target: [.nan, 5]}\n"))


def test_point_numbers_do_not_depend_on_their_place(tmp_path):
    from farm.games.sweep import SweepRun, run_sweep

    common = "name: t\ngames_per_point: 3\nbase: {n_evaders: 1, t_max: 10}\n"
    a = load_sweep_config(write(tmp_path, common + "vary: {grid: {n_pursuers: [2, 3]}}\n"))
    b_path = tmp_path / "b.yaml"
    b_path.write_text(common + "vary: {grid: {n_pursuers: [1, 3]}}\n")
    b = load_sweep_config(b_path)
    ga = (run_sweep(a, tmp_path / "a", use_ray=False, show_progress=False), SweepRun(a, tmp_path / "a").read_games())[1]
    gb = (run_sweep(b, tmp_path / "b", use_ray=False, show_progress=False), SweepRun(b, tmp_path / "b").read_games())[1]
    three_a = ga[ga["point"] == 1].drop(columns=["point"]).reset_index(drop=True)
    three_b = gb[gb["point"] == 1].drop(columns=["point"]).reset_index(drop=True)
    times = ["capture_times", "escape_times"]
    assert three_a.drop(columns=times).equals(three_b.drop(columns=times))


def test_exit_point_and_speeds_can_be_set_and_varied(tmp_path):
    from farm.games.sweep import VARIABLE_FIELDS

    assert {"exit_point", "pursuer_speed", "evader_speed"} <= set(VARIABLE_FIELDS)
    default = load_sweep_config(write(tmp_path, "name: t\nbase: {n_pursuers: 3, n_evaders: 1}\n")).points()[0].case
    assert (default.exit_point, default.pursuer_speed, default.evader_speed) == (None, 1.0, 1.0)
    cfg = load_sweep_config(write(tmp_path, """
        name: t
        base: {n_pursuers: 3, n_evaders: 1, exit_point: [0, 5], evader_speed: 0.5}
        vary:
          grid: {pursuer_speed: [1, 2]}
          zip: {exit_point: [[0, 5], null]}
          random: {n: 2, ranges: {evader_speed: [0.5, 1.5]}}
    """))
    points = cfg.points()
    assert len(points) == 2 * 2 * 2
    assert {p.case.pursuer_speed for p in points} == {1.0, 2.0}
    assert {p.case.exit_point for p in points} == {(0.0, 5.0), None}
    assert all(0.5 <= p.case.evader_speed <= 1.5 for p in points) and len({p.case.evader_speed for p in points}) == 2
    assert len({p.case.key() for p in points}) == len(points)
    base_only = load_sweep_config(write(tmp_path, "name: t\nbase: {n_pursuers: 3, n_evaders: 1, exit_point: [0, 5], "
                                                  "evader_speed: 0.5}\n"))
    assert base_only.points()[0].case.exit_point == (0.0, 5.0) and base_only.points()[0].case.evader_speed == 0.5
    plain = load_sweep_config(write(tmp_path, "name: t\nbase: {n_pursuers: 3, n_evaders: 1}\n"))
    assert base_only.sweep_id() != plain.sweep_id()


def test_default_shard_size_follows_the_engines_cost_model():
    """About half a second of work per shard by the engine's cost model: more games of
    cheap cases, fewer of dear ones (more agents, cells, slower pursuers, longer t_max)."""
    from farm.games.shards import SHARD_SECONDS
    from farm.games.shards import games_per_shard as default_shard_games
    from workers import Case
    from workers.engine import estimated_game_seconds

    def seconds(c):
        return estimated_game_seconds(c.n_pursuers, c.n_evaders, c.pursuer_policy, c.evader_policy, c.t_max, c.dt,
                                      c.pursuer_speed, c.evader_speed)

    cheap = Case(5, 1, pursuer_policy="pure_pursuit", evader_policy="target")
    paper, dear, slow, short = Case(5, 1), Case(100, 50), Case(5, 1, pursuer_speed=0.5), Case(5, 1, t_max=2.0)
    for case in (cheap, paper, dear, slow, short):
        n = default_shard_games(case)
        assert n == 1 or 0.5 * SHARD_SECONDS <= n * seconds(case) <= 2 * SHARD_SECONDS
    assert default_shard_games(cheap) > default_shard_games(paper) > default_shard_games(dear) >= 1
    assert default_shard_games(slow) < default_shard_games(paper) < default_shard_games(short)
