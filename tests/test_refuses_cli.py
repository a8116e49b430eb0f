"""What the command line refuses (issue 17): contradictory or ignored flags, empty entries,
addresses that are not addresses, jobs too big to run blind, a damaged sweep.json; and
negative numbers that need no '='."""

import json
import subprocess
import time

import pandas as pd
import pytest
import yaml

from farm.games.sizes import JobSize, check_size

from helpers import farm_in_repo, farm_refusal


# `farm` in this process (farm_in_repo): every command here is refused before Ray starts or runs
# --no-ray (conftest's RAY_ADDRESS of a closed port would fail any that joined Ray).
farm = farm_in_repo


def one_line_error(r, *words):
    """farm's one-line refusal in r (farm_refusal), holding every word; returns the line."""
    return farm_refusal(r.returncode, r.stderr, *words)


@pytest.mark.parametrize("args,first,second", [
    (("--pursuers", "4,5", "--evaders", "8,5", "--n-pursuers", 3), "--pursuers", "--n-pursuers"),
    (("--pursuers", "4,5", "--evaders", "8,5", "--n-evaders", 2), "--evaders", "--n-evaders"),
    (("--positions", "p.json", "--pursuers", "4,5", "--evaders", "8,5"), "--positions", "--pursuers"),
    (("--pursuers", "4,5", "--evaders", "8,5", "--seed", 3), "--pursuers", "--seed"),
    (("--pursuers", "4,5", "--evaders", "8,5", "--law", "uniform"), "--pursuers", "--law"),
])
def test_game_contradictory_flags_name_both(args, first, second):
    one_line_error(farm("game", *args), first, second)


def test_game_ignored_and_empty_entries():
    one_line_error(farm("game", "--plot-times", "0,1"), "--plot-times", "--plot")
    one_line_error(farm("game", "--pursuers", "4,5;;4,2", "--evaders", "8,5"), "--pursuers", "empty entry")
    one_line_error(farm("game", "--pursuers", "4,5", "--evaders", "8,5,"), "--evaders", "empty entry")


def test_negative_numbers_need_no_equals_sign():
    r = farm("game", "--pursuers", "4,5", "--evaders", "8,5", "--evader-policy", "target", "--target", "-1,5")
    assert r.returncode == 0, r.stderr
    one_line_error(farm("game", "--dt", "-1"), "--dt")


@pytest.mark.parametrize("address", ["notahost", "ray://", "10.0.0.5"])
def test_address_that_is_not_one_is_one_line(address, tmp_path):
    one_line_error(farm("sweep", "configs/smoke.yaml", "--out", tmp_path / "o", "--address", address), address)


def test_sweep_flags_that_contradict(tmp_path):
    for extra, words in ((("--no-ray", "--workers", 2), ("--no-ray", "--workers")),
                         (("--no-ray", "--address", "127.0.0.1:1"), ("--no-ray", "--address")),
                         (("--address", "127.0.0.1:1", "--metrics-port", 9000), ("--address", "--metrics-port"))):
        one_line_error(farm("sweep", "configs/smoke.yaml", "--out", tmp_path / "o", *extra), *words)
    one_line_error(farm("table", "show", "configs/table_small.yaml", "--workers", 2), "--workers")


def write(path, doc):
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_huge_jobs_say_their_size_and_are_refused_at_once_unless_yes(tmp_path):
    values = list(range(1, 11))
    sweep = write(tmp_path / "huge.yaml", {"name": "huge", "games_per_point": 1000,
                                           "base": {"n_pursuers": 3, "n_evaders": 1},
                                           "vary": {"grid": {"n_pursuers": values, "n_evaders": values,
                                                             "t_max": [10.0 + v for v in values],
                                                             "tau": [float(v) for v in values],
                                                             "pursuer_speed": [float(v) for v in values],
                                                             "evader_speed": [float(v) for v in values],
                                                             "dt": [0.01 * v for v in values],
                                                             "capture_radius": [0.1 * v for v in values],
                                                             "target": [[0.0, float(v)] for v in values]}}})
    t0 = time.perf_counter()
    line = one_line_error(farm("sweep", sweep, "--out", tmp_path / "o"), "1,000,000,000 points", "--yes", "CPU")
    assert time.perf_counter() - t0 < 60 and "memory" in line
    assert not (tmp_path / "o").exists()  # nothing planned, nothing written
    table = write(tmp_path / "t.yaml", {"name": "big", "store": str(tmp_path / "s.sqlite"),
                                        "n_pursuers": list(range(1, 1001)), "n_evaders": list(range(1, 1001))})
    one_line_error(farm("table", table), "1,000,000 cases", "--yes")
    assert not (tmp_path / "s.sqlite").exists()
    one_line_error(farm("pe-table", "--games", 1_000_000_000, "--out", tmp_path / "pe"), "6,000,000,000 games",
                   "--yes")


def test_a_job_over_ten_cpu_minutes_says_its_size_first(capsys):
    check_size(JobSize("sweep", 10, "point", 1000, 1200.0, 10), yes=False, cpus=2)
    err = capsys.readouterr().err
    assert err.startswith("farm: sweep of 10 points, 1,000 games: about 20 min of CPU time") and "10 min on 2" in err
    check_size(JobSize("sweep", 10, "point", 1000, 10.0, 10), yes=False)
    assert capsys.readouterr().err == ""  # small jobs just run
    check_size(JobSize("sweep", 10, "point", 10**9, 1e9, 10), yes=True)  # over the limit, but asked for
    assert "years" in capsys.readouterr().err


SMALL = {"name": "rebuild", "seed": 2, "games_per_point": 6, "shard_games": 3,
         "base": {"n_pursuers": 2, "n_evaders": 1, "t_max": 5},
         "vary": {"grid": {"evader_policy": ["centroid", "constant_area"]}}}


def test_a_damaged_sweep_json_is_rebuilt_from_the_config_when_the_shards_match(tmp_path):
    config = write(tmp_path / "s.yaml", SMALL)
    out = tmp_path / "out"
    assert farm("sweep", config, "--out", out, "--no-ray", "--quiet").returncode == 0
    before = pd.read_csv(out / "summary.csv")
    manifest = json.loads((out / "sweep.json").read_text())
    (out / "sweep.json").write_text('{"sweep_id": "12')  # damaged
    one_line_error(farm("sweep", config, "--out", out, "--no-ray"), "sweep.json is damaged", "--rebuild")
    other = write(tmp_path / "other.yaml", {**SMALL, "seed": 3})
    one_line_error(farm("sweep", other, "--out", out, "--no-ray", "--rebuild"), "belongs to sweep")
    r = farm("sweep", config, "--out", out, "--no-ray", "--quiet", "--rebuild")
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "sweep.json").read_text()) == manifest
    pd.testing.assert_frame_equal(pd.read_csv(out / "summary.csv"), before)

    (out / "sweep.json").unlink()  # deleted: the folder "holds no sweep" until rebuilt
    one_line_error(farm("sweep", config, "--out", out, "--no-ray"), "holds no sweep.json", "--rebuild")
    assert farm("sweep", config, "--out", out, "--no-ray", "--quiet", "--rebuild").returncode == 0
    assert json.loads((out / "sweep.json").read_text()) == manifest


def test_a_read_only_out_is_refused_before_any_game(tmp_path, capsys):
    """Issue 28's finding: `farm pe-table --out` under a read-only folder found it only after
    every game was played. Now it is one line at once (chattr +i: root cannot write either)."""
    from farm.cli import main

    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["chattr", "+i", str(ro)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available here")
    try:
        for out, where in ((ro, "it is"), (ro / "pe", f"its folder {ro} is")):
            code = main(["pe-table", "--games", "2", "--out", str(out), "--no-figures"])
            err = capsys.readouterr().err.strip()
            assert code == 2 and "\n" not in err and f"--out: {out} cannot be written ({where} read-only)" in err
        assert list(ro.iterdir()) == []
    finally:
        subprocess.run(["chattr", "-i", str(ro)], check=True)


@pytest.mark.parametrize("flag, args", [
    ("--out", ["sweep", "configs/smoke.yaml", "--no-ray", "--quiet", "--out", "RO/sweep"]),
    ("--out", ["suite", "configs/suite_demo.yaml", "--quiet", "--out", "RO/suite"]),
    ("--out", ["train", "configs/train/tiny.yaml", "--quiet", "--out", "RO/run"]),
    ("--out", ["experiments", "configs/experiments/smoke.yaml", "--quiet", "--out", "RO/experiment"]),
    ("--plot", ["game", "--n-pursuers", "3", "--n-evaders", "1", "--plot", "RO/game.png"]),
    ("--animate", ["game", "--n-pursuers", "3", "--n-evaders", "1", "--animate", "RO/game.gif"]),
    ("-o", ["report", "results", "-o", "RO/report.html"]),
])
def test_every_command_refuses_a_read_only_destination_before_any_work(flag, args, tmp_path):
    """The same finding in every other command that writes: `farm suite` warmed its lattice and
    played every episode before a read-only --out failed, `farm game --animate` played the game
    and then ended in a traceback, `farm report -o` built the page first, and sweep, train and
    experiments failed without naming the flag. Now each says so in one line naming the flag,
    before any work (no Ray: conftest's RAY_ADDRESS of a closed port), and writes nothing."""
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["chattr", "+i", str(ro)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available here")
    path = next(a for a in args if a.startswith("RO/")).replace("RO", str(ro))
    try:
        t0 = time.perf_counter()
        r = farm(*[a.replace("RO", str(ro)) for a in args])
        line = one_line_error(r, f"{flag}: {path} cannot be written (its folder {ro} is read-only)")
        assert time.perf_counter() - t0 < 20, line
        assert list(ro.iterdir()) == []
    finally:
        subprocess.run(["chattr", "-i", str(ro)], check=True)
