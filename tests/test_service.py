"""The capture-time service: store, keys, client memo, the Ray actor (restart,
single-flight under 8 concurrent clients, estimates, metrics), bad input."""

import math
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import replace

import pytest

from farm.service import CaptureTimeClient, GameSettings, StatsStore, StoreCorruptError
from farm.service.lookup import LocalBackend, compute_in_process
from workers import CaptureStats, Case, InitialLaw, InputError, run_case

FAST = GameSettings.of(games=6, t_max=20.0)


def same(a: CaptureStats, b: CaptureStats) -> bool:
    """Equal statistics (NaN equal to NaN), both computed from games."""
    fa, fb = a.flat(), b.flat()
    return a.estimate is None and b.estimate is None and fa.keys() == fb.keys() and all(
        (x == y) or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
        for x, y in ((fa[k], fb[k]) for k in fa)
    )


def test_value_is_the_case_statistics(tmp_path):
    client = CaptureTimeClient(FAST, local_store=tmp_path / "s.sqlite")
    v = client.get(3, 2)
    assert isinstance(v, CaptureStats)
    case = Case(3, 2, t_max=20.0)
    per_game, summary = run_case(case, 6, seed=0)
    assert same(v, summary)  # bit for bit: game g is default_rng([seed, g]) on both paths
    assert v.n_games == 6 and v.estimate is None
    assert v.frac_escaped == 0.0 and v.frac_escaped_tau == 0.0  # no exit: nobody escapes


def test_miss_computes_stores_and_reloads(tmp_path):
    path = tmp_path / "s.sqlite"
    a = CaptureTimeClient(FAST, local_store=path)
    v = a.get(2, 1)
    assert a.stats()["computations"] == {a.key(2, 1).digest(): 1}
    assert a.get(2, 1) is v  # memo hit
    b = CaptureTimeClient(FAST, local_store=path)
    assert same(b.get(2, 1), v) and b.stats()["computations"] == {}


def test_stats_count_the_distinct_keys_asked(tmp_path):
    """`asked`: the distinct keys asked, however often, computed or found in the store."""
    path = tmp_path / "s.sqlite"
    k21, k31 = FAST.key(2, 1), FAST.key(3, 1)
    cold = LocalBackend(path)
    cold.get_many([k21, k21, k31])
    cold.get_many([k21])
    stats = cold.stats()
    assert stats["asked"] == 2 and stats["misses"] == 3 and stats["computations"] == {k21.digest(): 1, k31.digest(): 1}
    cold.close()
    warm = LocalBackend(path)
    warm.get_many([k31])
    assert warm.stats()["asked"] == 1 and warm.stats()["computations"] == {}
    warm.close()


def test_keys_differing_in_any_parameter_never_collide():
    base = FAST.key(3, 2)
    variants = [
        FAST.key(2, 2), FAST.key(3, 1), FAST.with_(pursuer_policy="pure_pursuit").key(3, 2),
        FAST.with_(evader_policy="target").key(3, 2), FAST.with_(capture_radius=0.3).key(3, 2),
        FAST.with_(dt=0.02).key(3, 2), FAST.with_(t_max=21.0).key(3, 2), FAST.with_(tau=4.0).key(3, 2),
        FAST.with_(target=(0.0, 4.0)).key(3, 2), FAST.with_(games=7).key(3, 2), FAST.with_(seed=1).key(3, 2),
        FAST.with_(arena=((0, 0), (10, 0), (10, 10), (0, 10))).key(3, 2),
        FAST.with_(law=InitialLaw(kind="uniform")).key(3, 2),
        FAST.with_(exit_point=(0.0, 5.0)).key(3, 2), FAST.with_(pursuer_speed=2.0).key(3, 2),
        FAST.with_(evader_speed=0.5).key(3, 2),
    ]
    digests = {base.digest()} | {k.digest() for k in variants}
    assert len(digests) == len(variants) + 1
    stale = replace(base, case=replace(base.case, engine_version="0.0.1"))
    assert stale.digest() != base.digest()


@pytest.mark.parametrize(
    "args,message",
    [((-1, 2), "n_pursuers: must be a whole number >= 1"), ((2, 0), "n_evaders: must be"),
     ((2.5, 1), "n_pursuers"), ((True, 1), "n_pursuers")],
)
def test_bad_team_sizes(tmp_path, args, message):
    path = tmp_path / "s.sqlite"
    client = CaptureTimeClient(FAST, local_store=path)
    client.get(1, 1)
    with pytest.raises(InputError, match=message):
        client.get(*args)
    assert CaptureTimeClient(FAST, local_store=path).stats()["stored"] == 1


def test_bad_settings(tmp_path):
    with pytest.raises(InputError, match="pursuer_policy: unknown policy"):
        FAST.with_(pursuer_policy="chase").key(1, 1)
    with pytest.raises(InputError, match="games: must be a whole number >= 2"):
        FAST.with_(games=1).key(1, 1)
    with pytest.raises(InputError, match="capture_radius"):
        FAST.with_(capture_radius=-1.0).key(1, 1)
    with pytest.raises(InputError, match=r"exit_point: must be a finite point \(x, y\)"):
        FAST.with_(exit_point=(math.nan, 5.0)).key(1, 1)
    with pytest.raises(InputError, match="pursuer_speed: must be positive and finite"):
        FAST.with_(pursuer_speed=0.0).key(1, 1)
    with pytest.raises(InputError, match="evader_speed: must be positive and finite"):
        GameSettings.of(evader_speed=-1).key(1, 1)


def test_exit_point_and_speeds_are_settings(tmp_path):
    s = GameSettings.of(exit_point=(0.0, 5.0), pursuer_speed=2.0)
    key = s.key(3, 2)
    assert key.case.exit_point == (0.0, 5.0) and key.case.pursuer_speed == 2.0 and key.case.evader_speed == 1.0
    assert key.digest() != GameSettings.of().key(3, 2).digest()
    assert key.settings_digest() != GameSettings.of().key(3, 2).settings_digest()
    assert GameSettings.of(exit_point=[0, 5], pursuer_speed=2).key(3, 2).digest() == key.digest()
    assert key.to_dict()["case"]["exit_point"] == [0.0, 5.0]
    from farm.service.table import load_table_config

    config = tmp_path / "t.yaml"
    config.write_text("name: t\nsettings: {games: 4, exit_point: [0, 5], pursuer_speed: 2}\n"
                      "n_pursuers: [3]\nn_evaders: [2]\n")
    assert load_table_config(config).keys()[0][3].digest() == GameSettings.of(
        games=4, exit_point=(0.0, 5.0), pursuer_speed=2.0).key(3, 2).digest()


def test_escape_statistics_reach_the_service(tmp_path):
    settings = GameSettings.of(games=4, t_max=12.0, tau=10.0, pursuer_policy="pure_pursuit",
                                  evader_policy="target", exit_point=(0.0, 5.0), pursuer_speed=0.5)
    v = CaptureTimeClient(settings, local_store=tmp_path / "s.sqlite").get(1, 2)
    _, summary = run_case(settings.key(1, 2).case, 4, seed=0)
    assert v.frac_escaped_tau == summary.frac_escaped_tau > 0
    assert v.first_escape.mean == summary.first_escape.mean


def test_damaged_row_is_reported_and_never_served(tmp_path):
    path = tmp_path / "s.sqlite"
    good = CaptureTimeClient(FAST, local_store=path).get(2, 2)
    db = sqlite3.connect(path)
    db.execute("UPDATE stats SET value_json = replace(value_json, '\"n_games\": 6', '\"n_games\": 7')")
    db.commit()
    db.close()
    client = CaptureTimeClient(FAST, local_store=path)
    assert client.stats()["corrupt_rows"]  # reported on load
    v = client.get(2, 2)  # recomputed, not the damaged row
    assert v.n_games == 6 and same(v, good)
    assert client.stats()["computations"]


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_damaged_store_file_is_detected(tmp_path, damage):
    path = tmp_path / "s.sqlite"
    client = CaptureTimeClient(FAST, local_store=path)
    for n in range(1, 4):
        client.get(n, 1)
    client.backend.store.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    client.backend.store.close()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if damage == "truncate" else data[:100] + b"\x00garbage" * 500)
    with pytest.raises(StoreCorruptError, match="the capture-time store is damaged"):
        StatsStore(path)
    config = tmp_path / "t.yaml"
    config.write_text(f"name: t\nstore: {path}\nn_pursuers: [1]\nn_evaders: [1]\n")
    r = subprocess.run([sys.executable, "-m", "farm.cli", "table", "show", str(config)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "damaged" in r.stderr


def test_estimate_from_neighbours_is_flagged(tmp_path):
    client = CaptureTimeClient(FAST, local_store=tmp_path / "s.sqlite")
    a, b = client.get(2, 1), client.get(4, 1)
    est = client.get_many([(3, 1)], estimate=True)[0]
    assert est.n_games == 0 and "(2,1)" in est.estimate and "(4,1)" in est.estimate
    assert est.mean_capture.mean == pytest.approx(0.5 * (a.mean_capture.mean + b.mean_capture.mean))
    assert est.frac_captured_tau == pytest.approx(0.5 * (a.frac_captured_tau + b.frac_captured_tau))
    assert client.get(3, 1).estimate is None  # estimates are not memoized


def test_estimates_reopened_store_and_other_settings(tmp_path):
    """A reopened store's cases serve estimates from memory; another setting's cases never do."""
    path = tmp_path / "s.sqlite"
    CaptureTimeClient(FAST, local_store=path).get_many([(2, 1), (4, 1)])
    CaptureTimeClient(FAST.with_(tau=1.0), local_store=path).get_many([(3, 1)])
    service = LocalBackend(path)
    assert sorted(n[:2] for n in service.index.neighbours(FAST.key(3, 1))) == [(2, 1), (4, 1)]
    est = service.get_many([FAST.key(3, 1)], True)[0]
    assert est.estimate and "(3,1)" not in est.estimate
    service.get_many([FAST.key(5, 1)])  # computed: now a neighbour too
    assert sorted(n[:2] for n in service.index.neighbours(FAST.key(3, 1))) == [(2, 1), (4, 1), (5, 1)]


# ---------------------------------------------------------------- on Ray


@pytest.mark.ray
@pytest.mark.slow
def test_actor_miss_restart_and_single_flight(ray_local, tmp_path):
    import ray

    from farm.service import get_service

    store = tmp_path / "s.sqlite"
    service = get_service(store, name="svc-test")
    client = CaptureTimeClient(FAST, service=service)
    v = client.get(2, 2)
    assert ray.get(service.stats.remote())["computations"] == {FAST.key(2, 2).digest(): 1}
    assert same(v, next(compute_in_process([FAST.key(2, 2)]))[1])  # the farm computes what one process does

    ray.kill(service, no_restart=True)
    time.sleep(0.5)
    service = get_service(store, name="svc-test")
    stats = ray.get(service.stats.remote())
    assert stats["stored"] == 1 and stats["computations"] == {}
    assert same(CaptureTimeClient(FAST, service=service).get(2, 2), v)

    # 8 concurrent clients, overlapping keys: each key computed exactly once.
    pairs = [(n_p, n_e) for n_p in (1, 2, 3) for n_e in (1, 3)]
    results = [None] * 8

    def ask(i):
        c = CaptureTimeClient(FAST, service=get_service(store, name="svc-test"))
        mine = pairs[i % 3:] + pairs[: i % 3]
        results[i] = dict(zip(mine, c.get_many(mine)))

    threads = [threading.Thread(target=ask, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=600)
    stats = ray.get(service.stats.remote())
    new = {FAST.key(*p).digest() for p in pairs} - {FAST.key(2, 2).digest()}
    assert stats["computations"] == {d: 1 for d in new} and stats["asked"] == len(pairs) + 1  # and (2, 2)
    for p in pairs:
        assert all(same(r[p], results[0][p]) for r in results)

    # Estimates answer at once while the exact value is computed in the background.
    est = CaptureTimeClient(FAST, service=service).get_many([(4, 1)], estimate=True)[0]
    assert "nearest stored" in est.estimate
    deadline = time.time() + 120
    while FAST.key(4, 1).digest() not in ray.get(service.stats.remote())["computations"] and time.time() < deadline:
        time.sleep(0.2)
    assert CaptureTimeClient(FAST, service=service).get(4, 1).estimate is None

    # hits, misses, in-flight and compute seconds reach Prometheus.
    from farm.runtime.metrics import EXPORTED

    wanted = {m for m in EXPORTED if "_service_" in m}
    deadline, missing = time.time() + 60, wanted
    while missing and time.time() < deadline:
        text = urllib.request.urlopen(f"http://127.0.0.1:{ray_local}/metrics", timeout=10).read().decode()
        missing = {m for m in wanted if f"\n{m}{{" not in text and f"\n{m} " not in text}
        time.sleep(1)
    assert not missing, sorted(missing)


def test_rows_of_an_older_engine_are_left_out_not_fatal(tmp_path):
    """A store that also holds rows written by engine 1.x (no escape statistics in their
    values; their keys name the old engine, so no current key reads them) loads: those rows
    are left out and named, the current ones served."""
    import json

    from farm.service.store import _checksum

    path = tmp_path / "s.sqlite"
    good = CaptureTimeClient(FAST, local_store=path).get(2, 1)
    old_value = {k: v for k, v in good.flat().items() if "escape" not in k}
    old_key = json.dumps({"case": {**FAST.key(2, 1).case.to_dict(), "engine_version": "1.1.0"}, "games": 6,
                          "seed": 0}, sort_keys=True)
    value_json = json.dumps({**old_value, "expected_frac_captured_tau": 0.5, "estimate": False}, sort_keys=True)
    db = sqlite3.connect(path)
    db.execute("INSERT INTO stats VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
               ("old", "s", 2, 1, old_key, value_json, _checksum("old", old_key, value_json), 0.0))
    db.commit()
    db.close()
    client = CaptureTimeClient(FAST, local_store=path)
    assert client.backend.store.older_rows == {"old"} and not client.backend.store.corrupt_rows
    assert same(client.get(2, 1), good) and client.stats()["computations"] == {}
    assert len(StatsStore(path, read_only=True).table()) == 1
