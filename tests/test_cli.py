"""The `farm` CLI, run as a real subprocess: outputs, figures, and one-line errors (the table of
bad input through farm.cli.main in this process: the same one line, without an interpreter each)."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import farm_main
from helpers import farm_process as farm



def test_game_from_flags_with_plot(tmp_path):
    out = tmp_path / "g.png"
    r = farm("game", "--pursuers", "4,5;4,2", "--evaders", "8,5", "--plot", out, "--plot-times", "0,1,2")
    assert r.returncode == 0, r.stderr
    assert "evader 0 at (8.00, 5.00):" in r.stdout and " s" in r.stdout
    assert out.stat().st_size > 10_000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_game_from_json_matches_api(tmp_path):
    import numpy as np

    from workers import simulate_games

    pos = {"pursuers": [[3.5, 2.0], [4.5, 7.0]], "evaders": [[8.0, 5.0], [7.5, 1.0]]}
    f = tmp_path / "pos.json"
    f.write_text(json.dumps(pos))
    r = farm("game", "--positions", f, "--evader-policy", "constant_area")
    assert r.returncode == 0, r.stderr
    res = simulate_games(np.array([pos["pursuers"]]), np.array([pos["evaders"]]), evader_policy="constant_area")
    for t in res.capture_times[0]:
        assert f"{t:.2f} s" in r.stdout


@pytest.mark.slow
def test_pe_table_small(tmp_path):
    r = farm("pe-table", "--games", 4, "--out", tmp_path, "--format", "parquet")
    assert r.returncode == 0, r.stderr
    assert "Table 1: pure-distance pursuit" in r.stdout and "Table 2: area minimization" in r.stdout
    assert "3.373" in r.stdout and "3.31" in r.stdout
    df = pd.read_parquet(tmp_path / "pe_tables.parquet")
    assert len(df) == 6 and (df["games"] == 4).all()
    assert {"mean", "std", "ci95_low", "ci95_high", "min", "max", "paper_mean"} <= set(df.columns)
    assert (df["min"] <= df["mean"]).all() and (df["mean"] <= df["max"]).all()
    assert len(list(tmp_path.glob("fig_*.png"))) == 6
    games = pd.read_parquet(tmp_path / "pe_games.parquet")
    assert len(games) == 24
    assert "pursuer speed 1, evader speed 1 (the paper's)" in r.stdout and "sensitivity" not in r.stdout
    assert (df["pursuer_speed"] == 1.0).all() and (df["evader_speed"] == 1.0).all()


def test_pe_table_at_another_speed_ratio(tmp_path):
    r = farm("pe-table", "--games", 3, "--out", tmp_path, "--no-figures", "--pursuer-speed", 2)
    assert r.returncode == 0, r.stderr
    assert "pursuer speed 2, evader speed 1" in r.stdout and "(the paper's)" not in r.stdout
    assert "3.373" in r.stdout and "3.31" in r.stdout  # the paper's figures beside ours, unchanged
    assert "sensitivity check, not a fit" in r.stdout
    df = pd.read_csv(tmp_path / "pe_tables.csv")
    assert (df["pursuer_speed"] == 2.0).all() and (df["evader_speed"] == 1.0).all()
    from farm.games.pe_table import PAPER_CASES, paper_case
    from workers import Case

    keys = lambda base: {paper_case(base, n, pp, ep).key() for _, n, pp, ep, _ in PAPER_CASES}  # noqa: E731
    assert set(df["case_key"]) == keys(Case(1, 1, pursuer_speed=2.0))
    assert set(df["case_key"]).isdisjoint(keys(Case(1, 1)))  # not the equal-speed cases


def test_game_with_exit_point_and_speeds():
    """An evader 1.005 from an unguarded exit, heading for it at unit speed, escapes after
    the move that brings it within r_c = 0.25: step 76, t = 0.76 s."""
    r = farm("game", "--pursuers", "9,9", "--evaders", "1.005,5", "--pursuer-policy", "pure_pursuit",
             "--evader-policy", "target", "--exit-point", "0,5", "--pursuer-speed", "1.5")
    assert r.returncode == 0, r.stderr
    assert "(pursuer speed 1.5, exit at (0, 5))" in r.stdout
    assert "evader 0 at (1.0" in r.stdout and "5.00): escaped at 0.76 s" in r.stdout
    r = farm("game", "--n-pursuers", 2, "--evader-speed", "0.5", "--t-max", 20)
    assert r.returncode == 0, r.stderr
    assert "(evader speed 0.5)" in r.stdout and "escaped" not in r.stdout


@pytest.mark.parametrize(
    "args,message",
    [
        (["game", "--pursuers", "4,5", "--evaders", "18,5"],
         "evaders: agent 0 of game 0 at (18, 5) is outside the arena"),
        (["game", "--pursuers", "4,5", "--evaders", "8,5", "--dt", "-1"], "dt: must be positive"),
        (["game", "--pursuers", "4,5", "--evaders", "8"], "--evaders: expected x,y pairs"),
        (["game", "--pursuers", "4,nan", "--evaders", "8,5"], "pursuers: positions must be finite"),
        (["game", "--pursuer-policy", "chase"], "--pursuer-policy: unknown policy 'chase'"),
        (["game", "--n-pursuers", "0"], "--n-pursuers: must be a whole number >= 1"),
        (["game", "--positions", "/nonexistent.json"], "--positions: no such file"),
        (["game", "--arena", "ARENA_BAD"], "arena: polygon must be strictly convex"),
        (["game", "--t-max", "abc"], "--t-max: Input should be a valid number"),
        (["pe-table", "--games", "1"], "--games: need at least 2"),
        (["game", "--exit-point", "1"], "--exit-point: expected 2 numbers"),
        (["game", "--exit-point", "nan,5"], "--exit-point: must be a finite point (x, y), got (nan, 5.0)"),
        (["game", "--pursuers", "4,5", "--evaders", "8,5", "--exit-point", "inf,5"], "--exit-point: must be a finite"),
        (["game", "--pursuer-speed", "0"], "--pursuer-speed: must be positive and finite, got 0.0"),
        (["game", "--pursuers", "4,5", "--evaders", "8,5", "--evader-speed", "nan"],
         "--evader-speed: must be positive"),
        (["game", "--evader-speed", "fast"], "--evader-speed: Input should be a valid number"),
        (["pe-table", "--pursuer-speed", "-2"], "--pursuer-speed: must be positive and finite, got -2.0"),
        (["pe-table", "--evader-speed", "inf"], "--evader-speed: must be positive and finite, got inf"),
        (["robust", "configs/robust/smoke.yaml", "--seed", "-1"], "--seed: must be a whole number >= 0, got -1"),
        (["nope"], "invalid choice: 'nope'"),
    ],
)
def test_bad_cli_input_is_one_line(args, message, tmp_path):
    bad_arena = tmp_path / "arena.json"
    bad_arena.write_text(json.dumps([[0, 0], [10, 0], [5, 5], [10, 10], [0, 10]]))
    args = [str(bad_arena) if a == "ARENA_BAD" else a for a in args]
    status, _, stderr = farm_main(*args)
    assert status == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("farm: error: ") and message in lines[0]
    assert "Traceback" not in stderr


def test_unreachable_address_fails_at_once(tmp_path):
    """Ray would retry an address where nothing listens for minutes; farm says so in one line."""
    import time

    from conftest import free_port

    address = f"127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    r = farm("sweep", Path(__file__).resolve().parents[1] / "configs/smoke.yaml", "--address", address,
             "--out", tmp_path / "out")
    assert time.monotonic() - t0 < 60
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"address {address}: no Ray cluster answers there" in lines[0], r.stderr
    assert not list((tmp_path / "out").rglob("*.parquet"))


def test_game_with_given_positions_in_any_arena(tmp_path):
    """Given starts need no start boxes: a hexagon that does not hold the paper's boxes works."""
    hexagon = tmp_path / "hexagon.json"
    hexagon.write_text(json.dumps([[5 + 4 * np.cos(a), 5 + 4 * np.sin(a)] for a in np.arange(6) * np.pi / 3]))
    r = farm("game", "--pursuers", "4,5;5,4", "--evaders", "6,6", "--arena", hexagon, "--evader-policy",
             "constant_area")
    assert r.returncode == 0, r.stderr
    assert "2 pursuer(s) area_min vs 1 evader(s) constant_area" in r.stdout and " s" in r.stdout
    r = farm("game", "--arena", hexagon)  # sampled starts do need the boxes inside the arena
    assert r.returncode == 2 and "--law: pursuer_box" in r.stderr and "is not inside the arena" in r.stderr
