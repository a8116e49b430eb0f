"""`farm report`: a small real run rendered in headless Chromium, bad input, and an experiment's section
(a hand-built experiment folder: its summary, claims and learning curves over seeds)."""

import os
import re
import shutil
import subprocess
import tempfile

import numpy as np
import pytest
from helpers import farm_process as farm

from test_claims import STEPS, make_experiment  # a hand-built experiment folder whose numbers are known
from workers import ENGINE_VERSION
from farm.service import CaptureTimeClient, GameSettings

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-quic"]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    assert farm("pe-table", "--games", 3, "--out", root / "pe-table").returncode == 0
    assert farm("game", "--n-pursuers", 3, "--seed", 2, "--plot", root / "game.png").returncode == 0
    sweep = root.parent / "sweep.yaml"
    sweep.write_text("name: tiny\ngames_per_point: 4\nbase: {n_evaders: 1, t_max: 20}\n"
                     "vary: {grid: {n_pursuers: [1, 2]}}\n")
    assert farm("sweep", sweep, "--out", root / "sweep", "--no-ray", "--quiet").returncode == 0
    client = CaptureTimeClient(GameSettings.of(games=3, t_max=15.0), local_store=root / "capture_times.sqlite")
    client.get_many([(1, 1), (2, 1), (1, 2), (2, 2)])
    client.backend.store.close()
    return root


def browser(*args, timeout=120):
    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing on CI: `make browser` should have installed it")
        pytest.skip("chromium is not installed (make browser installs it)")
    with tempfile.TemporaryDirectory() as profile:
        return subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True,
                              text=True, timeout=timeout)


@pytest.mark.slow
def test_report_renders_in_chromium(results, tmp_path):
    r = farm("report", results, "-o", tmp_path / "report.html")
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "report.html").read_text()
    assert not re.search(r'(src|href)="(https?:)?//', page), "the page must not need the network"
    for title in ("The paper&#x27;s pursuit-evasion tables", "Sweeps", "Capture-time service table", "Game figures"):
        assert f"<h2>{title}</h2>" in page
    assert "farm train CONFIG" in page and "farm eval RUN_DIR" in page  # sections without data say how
    assert "3.373" in page and "tiny" in page and f"engine {ENGINE_VERSION}" in page

    dom = browser("--virtual-time-budget=15000", "--dump-dom", (tmp_path / "report.html").as_uri()).stdout
    check = re.search(r'id="selfcheck" data-images="(\d+)" data-loaded="(\d+)" data-errors="(\d+)"', dom)
    assert check, dom[:500]
    images, loaded, errors = map(int, check.groups())
    assert images >= 10 and loaded == images and errors == 0

    shot = tmp_path / "shot.png"
    browser("--window-size=1280,3000", "--hide-scrollbars", f"--screenshot={shot}", (tmp_path / "report.html").as_uri())
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 50_000


@pytest.mark.slow
def test_report_bad_input_is_one_line_and_leaves_no_file(results, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    broken = tmp_path / "broken"
    shutil.copytree(results / "sweep", broken / "sweep")
    (broken / "sweep" / "summary.parquet").write_bytes(b"PAR1 not really")
    for folder, message in [(tmp_path / "nope", "no such folder"), (empty, "no results found"),
                            (broken, "summary.parquet: unreadable results file")]:
        out = tmp_path / f"{folder.name}.html"
        r = farm("report", folder, "-o", out)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert message in r.stderr and "Traceback" not in r.stderr
        assert not out.exists() and not list(tmp_path.glob(f".{out.name}.*"))


@pytest.mark.slow
def test_report_leaves_other_sqlite_files_alone(results, tmp_path):
    import sqlite3

    other = results / "unrelated.sqlite"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE notes (x TEXT)")
    db.commit()
    db.close()
    before = other.read_bytes()
    assert farm("report", results, "-o", tmp_path / "r.html").returncode == 0
    assert other.read_bytes() == before and not other.with_name("unrelated.sqlite-wal").exists()
    other.unlink()


T975_2 = 4.302652729911275  # scipy.stats.t.ppf(0.975, 2): the 95% t interval of 3 values


def test_the_band_over_seeds_by_hand():
    from farm.core.stats import seed_band

    returns = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 8.0]])  # 3 seeds x 2 evaluations
    mean, low, high, kind = seed_band(returns)
    half = T975_2 * np.array([2.0, np.sqrt(13.0)]) / np.sqrt(3)  # sd of (0, 2, 4) is 2, of (1, 3, 8) sqrt(13)
    assert kind == "95% CI over seeds" and mean.tolist() == [2.0, 4.0]
    assert np.allclose(low, mean - half) and np.allclose(high, mean + half)
    mean, low, high, kind = seed_band(returns[:2])
    assert kind == "min-max of 2 seeds" and mean.tolist() == [1.0, 2.0]
    assert low.tolist() == [0.0, 1.0] and high.tolist() == [2.0, 3.0]
    mean, low, high, kind = seed_band(returns[:1])
    assert kind == "1 seed, no band" and mean.tolist() == low.tolist() == high.tolist() == [0.0, 1.0]


def test_learning_curves_take_finished_trials_on_common_timesteps(tmp_path):
    """Point 0: 3 finished seeds, one evaluated at 3 of the 5 timesteps (aligned on those 3);
    point 1: its seed 2 unfinished (2 evaluations, no result.json) is left out."""
    from farm.studies.experiments.results import point_curves, read_manifest

    folder = make_experiment(tmp_path)
    p0, p1 = point_curves(folder, read_manifest(folder))
    assert (p0.point, p0.seeds, p0.label) == (0, (0, 1, 2), "env.c_capture=0.0")
    assert p0.timesteps.tolist() == [4000, 12000, 20000]
    assert p0.returns.tolist() == [[-3, -0.5, -0.5], [-3, -2, -1], [-2, -1, 0]]
    assert p1.seeds == (0, 1) and p1.timesteps.tolist() == STEPS and p1.returns.shape == (2, 5)


def test_the_report_shows_an_experiment(tmp_path):
    """The Experiments section: the summary over seeds, the claims over seeds and the learning
    curves (inline; learning_curves.png beside the experiment is not shown again as a game
    figure); the page's images load in Chromium."""
    from farm.studies.claims import claims_over_seeds, write_claims_over_seeds
    from farm.studies.experiments.results import write_learning_curves
    from farm.report import build_report

    folder = make_experiment(tmp_path / "results" / "experiments")
    write_claims_over_seeds(folder, claims_over_seeds(folder))
    png = write_learning_curves(folder)
    assert png == folder / "learning_curves.png" and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = build_report(tmp_path / "results")
    section = page.split("<h2>Experiments</h2>", 1)[1].split("<h2>", 1)[0]
    assert "<h3>fake</h3>" in section and "5 of 6 trials finished" in section
    # point 0's td3 eliminated over seeds 0, 1, 2: 0.90, 0.91, 0.92; the best other: spread_evenly
    assert "0.910 ± " in section and "spread_evenly 0.950" in section
    assert "mixed (confirmed in 1 of 2 seeds)" in section
    assert 'alt="learning curves over seeds"' in section and "min-max for 2 seeds" in section
    assert "learning_curves.png" not in page.split("<h2>Game figures</h2>", 1)[1]
    (tmp_path / "report.html").write_text(page)
    dom = browser("--virtual-time-budget=15000", "--dump-dom", (tmp_path / "report.html").as_uri()).stdout
    images, loaded, errors = map(int, re.search(r'data-images="(\d+)" data-loaded="(\d+)" data-errors="(\d+)"',
                                                dom).groups())
    assert images >= 7 and loaded == images and errors == 0
