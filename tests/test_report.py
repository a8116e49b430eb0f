"""`farm report`: a small real run rendered in headless Chromium, and bad input."""

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from workers import ENGINE_VERSION
from farm.service import CaptureTimeClient, ServiceSettings

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-quic"]


def farm(*args):
    return subprocess.run([sys.executable, "-m", "farm.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    assert farm("pe-table", "--games", 3, "--out", root / "pe-table").returncode == 0
    assert farm("game", "--n-pursuers", 3, "--seed", 2, "--plot", root / "game.png").returncode == 0
    sweep = root.parent / "sweep.yaml"
    sweep.write_text("name: tiny\ngames_per_point: 4\nbase: {n_evaders: 1, t_max: 20}\nvary: {grid: {n_pursuers: [1, 2]}}\n")
    assert farm("sweep", sweep, "--out", root / "sweep", "--no-ray", "--quiet").returncode == 0
    client = CaptureTimeClient(ServiceSettings.of(games=3, t_max=15.0), local_store=root / "capture_times.sqlite")
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
