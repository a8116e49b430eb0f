"""Issue 17, the store and the service: bad input never becomes a wrong result.

- every column a reader uses is checksummed (v2 rows); rows written before (v1) read only
  when their columns agree with their key; a damaged row is reported, never served,
  recomputed;
- an estimate never divides 0 by 0 (a neighbour at distance 0, duplicate sizes);
- a store path that is a folder, or a store that cannot be written, is refused at once in
  one line naming the path (in process, and on Ray in the driver before any actor);
- an actor that dies of a project error raises that error's line, not Ray's wrapper.
"""

import math
import sqlite3
import time
from contextlib import contextmanager

import pytest
from hypothesis import HealthCheck, given, settings
from conftest import immutable
from helpers import one_line
from hypothesis import strategies as st

from farm.core.errors import ConfigError, StoreCorruptError
from farm.service import CaptureTimeClient, GameSettings, StatsStore
from farm.service.client import open_client
from farm.service.lookup import compute_in_process, estimate
from farm.service.store import _checksum, check_store, check_store_path
from workers import CaptureStats

SMALL = GameSettings.of(games=4, t_max=20.0)


def exact(a: CaptureStats, b: CaptureStats) -> bool:
    """The same statistics, NaN equal to NaN."""
    fa, fb = a.flat(), b.flat()
    return fa.keys() == fb.keys() and all(
        x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
        for x, y in ((fa[k], fb[k]) for k in fa))


def same_numbers(est: CaptureStats, value: CaptureStats) -> bool:
    """An estimate holding exactly a computed value's statistics (n_games 0: estimated)."""
    fe, fv = est.flat(), value.flat()
    return all(fe[k] == fv[k] or (math.isnan(fe[k]) and math.isnan(fv[k])) for k in fv if k != "n_games")


def filled(path, pairs=((2, 1), (4, 1))) -> dict:
    """A store at path holding SMALL's pairs: {pair: value}."""
    client = CaptureTimeClient(SMALL, local_store=path)
    values = dict(zip(pairs, client.get_many(list(pairs))))
    client.close()
    return values


def execute(path, sql, *args) -> None:
    db = sqlite3.connect(path)
    db.execute(sql, args)
    db.commit()
    db.close()


def as_written_before(path) -> None:
    """Rewrite every row's checksum as the store wrote it before issue 17 (v1)."""
    db = sqlite3.connect(path)
    for key, key_json, value_json in db.execute("SELECT key, key_json, value_json FROM stats").fetchall():
        db.execute("UPDATE stats SET checksum = ? WHERE key = ?", (_checksum(key, key_json, value_json), key))
    db.commit()
    db.close()


# ---------------------------------------------------------------- 1. every column a reader uses is checksummed
def test_new_rows_carry_a_v2_checksum(tmp_path):
    path = tmp_path / "s.sqlite"
    filled(path)
    checksums = [r[0] for r in sqlite3.connect(path).execute("SELECT checksum FROM stats")]
    assert len(checksums) == 2 and all(c.startswith("v2:") for c in checksums)


@pytest.mark.parametrize("written", ["now", "before"])
@pytest.mark.parametrize("column,damage", [("n_pursuers", "3"), ("n_evaders", "2"), ("settings", "'0000000000000000'")])
def test_a_damaged_column_is_reported_never_served_and_recomputed(tmp_path, written, column, damage):
    """Today's failure: one damaged team-size column (the checksum did not cover it) put a
    (2,1) value at (3,1) in the neighbour index, and the estimate of (3,1) was NaN (0/0)."""
    path = tmp_path / "s.sqlite"
    values = filled(path)
    if written == "before":
        as_written_before(path)
        assert not StatsStore(path).corrupt_rows and len(StatsStore(path).load_all()) == 2  # old rows read
    digest = SMALL.key(2, 1).digest()
    execute(path, f"UPDATE stats SET {column} = {damage} WHERE key = ?", digest)

    store = StatsStore(path)
    assert store.get(SMALL.key(2, 1)) is None and store.corrupt_rows == {digest}
    assert set(store.load_all()) == {SMALL.key(4, 1).digest()}
    assert [row[0] for row in store.rows()] == [SMALL.key(4, 1).digest()]
    store.close()

    client = CaptureTimeClient(SMALL, local_store=path)
    assert client.stats()["corrupt_rows"] == [digest]  # reported on load
    assert [n[:2] for n in client.backend.index.neighbours(SMALL.key(3, 1))] == [(4, 1)]
    est = client.get_many([(3, 1)], estimate=True)[0]
    flat = est.flat()
    assert est.estimate and "(4,1)" in est.estimate and "(2,1)" not in est.estimate
    assert math.isfinite(flat["mean_capture_mean"]) and math.isfinite(flat["frac_captured_tau_mean"])
    assert same_numbers(est, values[(4, 1)])  # the one verified neighbour's statistics
    again = client.get(2, 1)  # recomputed, exactly as before
    assert exact(again, values[(2, 1)]) and client.stats()["computations"] == {digest: 1}
    client.close()
    row = sqlite3.connect(path).execute("SELECT checksum, n_pursuers, n_evaders FROM stats WHERE key = ?",
                                        (digest,)).fetchone()
    assert row[0].startswith("v2:") and row[1:] == (2, 1)  # re-written whole


def test_rows_written_before_still_read_exactly(tmp_path):
    path = tmp_path / "s.sqlite"
    values = filled(path, ((2, 1), (4, 1), (3, 2)))
    as_written_before(path)
    client = CaptureTimeClient(SMALL, local_store=path)
    assert not client.stats()["corrupt_rows"]
    for pair, value in values.items():
        assert exact(client.get(*pair), value)
    assert client.stats()["computations"] == {}
    assert sorted(n[:2] for n in client.backend.index.neighbours(SMALL.key(3, 1))) == [(2, 1), (3, 2), (4, 1)]
    assert len(StatsStore(path, read_only=True).table()) == 3


def test_a_damaged_value_still_fails_its_checksum(tmp_path):
    path = tmp_path / "s.sqlite"
    filled(path)
    execute(path, "UPDATE stats SET value_json = replace(value_json, '\"n_games\": 4', '\"n_games\": 5')")
    store = StatsStore(path)
    assert store.load_all() == {} and len(store.corrupt_rows) == 2


def test_a_byte_of_a_checksum_that_is_not_utf8_is_a_damaged_row_not_a_crash(tmp_path, capsys):
    """Issue 28's finding: one flipped byte in a row's checksum (0xff: no UTF-8 text) ended
    `farm table show` in sqlite's "Could not decode to UTF-8" traceback."""
    path = tmp_path / "s.sqlite"
    values = filled(path)
    digest = SMALL.key(2, 1).digest()
    checksum = sqlite3.connect(path).execute("SELECT checksum FROM stats WHERE key = ?", (digest,)).fetchone()[0]
    data = bytearray(path.read_bytes())
    at = data.find(checksum.encode())
    assert at > 0 and data.find(checksum.encode(), at + 1) == -1  # the row's one copy, in the main file
    data[at + 5] = 0xFF
    path.write_bytes(bytes(data))

    store = StatsStore(path, read_only=True)
    assert len(store.table()) == 1 and store.corrupt_rows == {digest}
    store.close()
    client = CaptureTimeClient(SMALL, local_store=path)
    assert exact(client.get(2, 1), values[(2, 1)]) and client.stats()["computations"] == {digest: 1}
    client.close()
    assert not StatsStore(path, read_only=True).corrupt_rows  # recomputed, re-written whole


def test_a_copy_of_the_store_file_alone_holds_every_row(tmp_path):
    """Issue 28's finding: after `farm table` every row sat in the -wal file (the service's
    actor is killed with Ray, never closed), and a copy of the .sqlite file alone was empty.
    A connection still open, as the killed actor's, is the case."""
    path = tmp_path / "s.sqlite"
    store = StatsStore(path)
    keys = [SMALL.key(2, 1), SMALL.key(4, 1)]
    values = {keys[k]: value for k, value in compute_in_process(keys)}
    for key, value in values.items():
        store.put(key, value)
    copy = tmp_path / "copy.sqlite"
    copy.write_bytes(path.read_bytes())  # while the writer's connection is open
    assert not (tmp_path / "copy.sqlite-wal").exists()
    copied = StatsStore(copy, read_only=True)
    assert set(copied.load_all()) == {key.digest() for key in values} and not copied.corrupt_rows
    store.close()


# ---------------------------------------------------------------- 2. estimates never divide by zero
@pytest.fixture(scope="module")
def computed():
    """Three computed values of SMALL: {(n_p, n_e): CaptureStats}."""
    pairs = [(2, 1), (4, 1), (3, 2)]
    return {pairs[k]: v for k, v in compute_in_process([SMALL.key(*p) for p in pairs])}


def test_a_neighbour_at_distance_zero_is_the_estimate(computed):
    a, b = computed[(2, 1)], computed[(4, 1)]
    est = estimate(SMALL.key(2, 1), [(4, 1, b), (2, 1, a)])
    assert est.n_games == 0 and est.estimate and "(2,1)" in est.estimate and "(4,1)" not in est.estimate
    assert same_numbers(est, a)
    assert all(math.isfinite(v) for k, v in est.flat().items() if math.isfinite(a.flat()[k]))


def test_duplicate_sizes_weigh_alike(computed):
    a, b = computed[(2, 1)], computed[(4, 1)]
    both = estimate(SMALL.key(2, 1), [(2, 1, a), (2, 1, b)])  # two at distance 0: their mean
    assert both.mean_capture.mean == pytest.approx(0.5 * (a.mean_capture.mean + b.mean_capture.mean))
    apart = estimate(SMALL.key(3, 1), [(4, 1, a), (4, 1, b)])  # two at the same distance 1
    assert apart.mean_capture.mean == pytest.approx(0.5 * (a.mean_capture.mean + b.mean_capture.mean))


sizes = st.tuples(st.integers(1, 6), st.integers(1, 6))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=sizes, neighbours=st.lists(st.tuples(sizes, st.sampled_from([(2, 1), (4, 1), (3, 2)])), min_size=1,
                                      max_size=8))
def test_an_estimate_is_a_weighted_mean_of_its_neighbours(computed, key, neighbours):
    """Whatever the neighbours (the key's own sizes, duplicates): each statistic lies between
    its neighbours' and is finite wherever one of theirs is; never 0/0."""
    given_ = [(n_p, n_e, computed[which]) for (n_p, n_e), which in neighbours]
    est = estimate(SMALL.key(*key), given_).flat()
    used = [computed[which].flat() for _, which in neighbours]
    for name, value in est.items():
        if name == "n_games":
            continue
        xs = [float(u[name]) for u in used if math.isfinite(float(u[name]))]
        if xs and all(math.isfinite(float(u[name])) for u in used):
            assert math.isfinite(value) and min(xs) - 1e-9 <= value <= max(xs) + 1e-9, name


# ---------------------------------------------------------------- 3. a store path that is a folder
def test_a_folder_is_refused_at_once_in_one_line(tmp_path, monkeypatch):
    """Today: "the capture-time store is damaged (unable to open database file); move it aside"."""
    folder = tmp_path / "results" / "x"
    folder.mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    want = "store: results/x is a folder, not a capture-time store file"
    for make in (lambda: StatsStore("results/x"), lambda: StatsStore("results/x", read_only=True),
                 lambda: CaptureTimeClient(SMALL, local_store="results/x"), lambda: check_store("results/x")):
        with pytest.raises(ConfigError) as e:
            make()
        assert one_line(e.value) == want
    with pytest.raises(ConfigError) as e:
        with open_client(SMALL, mode="local", store="results/x"):
            pass
    assert one_line(e.value) == want
    assert list(folder.iterdir()) == []


def test_open_client_on_ray_refuses_a_folder_before_ray_starts(tmp_path, monkeypatch):
    import sys

    import farm.runtime

    if "ray" in sys.modules and sys.modules["ray"].is_initialized():
        pytest.skip("a Ray is running in this process (the pre-check is for a Ray this call would start)")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)

    @contextmanager
    def no_ray(*args, **kwargs):
        raise AssertionError("Ray was started")
        yield

    monkeypatch.setattr(farm.runtime, "ray_cluster", no_ray)
    with pytest.raises(ConfigError) as e:
        with open_client(SMALL, mode="ray", store=tmp_path):
            pass
    assert one_line(e.value) == f"store: {tmp_path} is a folder, not a capture-time store file"


def test_a_path_below_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError) as e:
        StatsStore(tmp_path / "f" / "s.sqlite")
    assert one_line(e.value) == f"store: {tmp_path / 'f' / 's.sqlite'}: {tmp_path / 'f'} is a file, not a folder"


# ---------------------------------------------------------------- 4. a read-only store


def test_a_read_only_store_file_is_refused_before_any_work(tmp_path, monkeypatch):
    """Today: computed first, then `sqlite3.OperationalError: attempt to write a readonly
    database`, no file named."""
    path = tmp_path / "s.sqlite"
    filled(path, ((1, 1),))
    played = []
    monkeypatch.setattr("farm.service.lookup.play_shard", lambda *a: played.append(a))
    with immutable(path):
        for make in (lambda: StatsStore(path), lambda: CaptureTimeClient(SMALL, local_store=path),
                     lambda: check_store(path)):
            with pytest.raises(ConfigError) as e:
                make()
            assert one_line(e.value) == (f"store: {path} is read-only (the file is not writable); "
                                   "make it writable or name another store")
        assert len(StatsStore(path, read_only=True).table()) == 1  # reading it is fine
    assert played == []


def test_a_store_in_a_read_only_folder_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    with immutable(folder):
        for path in (folder / "s.sqlite", folder / "new" / "s.sqlite"):
            with pytest.raises(ConfigError) as e:
                CaptureTimeClient(SMALL, local_store=path)
            assert one_line(e.value) == (f"store: {path} is read-only (its folder {folder} is not writable); "
                                   "make it writable or name another store")
        assert list(folder.iterdir()) == []


def test_the_write_check_is_a_real_write(tmp_path, monkeypatch):
    """When the permission bits say yes but SQLite cannot write (here: os.access patched to
    say yes on an immutable file), opening for writing tries a write that changes nothing."""
    path = tmp_path / "s.sqlite"
    filled(path, ((1, 1),))
    before = path.read_bytes()
    monkeypatch.setattr("farm.service.store.os.access", lambda *a, **k: True)
    with immutable(path):
        with pytest.raises(ConfigError) as e:
            StatsStore(path)
        assert one_line(e.value) == (f"store: {path} is read-only (attempt to write a readonly database); "
                               "make it writable or name another store")
    StatsStore(path).close()  # writable again: the check writes nothing
    assert len(StatsStore(path).load_all()) == 1
    assert path.read_bytes() == before


def test_check_store_path_is_the_same_check_unpatched(tmp_path):
    path = tmp_path / "s.sqlite"
    assert check_store_path(path) == path and not path.exists()  # creates nothing
    assert check_store(path) == path and not path.exists()


# ---------------------------------------------------------------- 5. on Ray: checked in the driver, one line
def test_project_error_of_rebuilds_the_error_ray_wraps():
    import ray

    from farm.service.actor import project_error_of

    msg = "/x/s.sqlite: the capture-time store is damaged (file is not a database); move it aside"
    text = (f"The actor died because of an error raised in its creation task, ray::svc:ServiceLookup.__init__()\n"
            f"  File \"/work/farm/service/store.py\", line 93, in __init__\n    raise StoreCorruptError(\n"
            f"farm.core.errors.StoreCorruptError: {msg}\n")
    e = project_error_of(ray.exceptions.RayActorError("abc", text, actor_init_failed=True))
    assert type(e) is StoreCorruptError and str(e) == msg
    assert project_error_of(ray.exceptions.RayActorError("abc", text, actor_init_failed=False)) is None
    other = text.replace("farm.core.errors.StoreCorruptError", "sqlite3.OperationalError")
    assert project_error_of(ray.exceptions.RayActorError("abc", other, actor_init_failed=True)) is None
    assert project_error_of(ValueError(text)) is None


def damaged_file(path):
    path.write_bytes(b"SQLite format 3\x00" + b"\x00garbage" * 500)
    return path


@pytest.mark.ray
def test_get_service_refuses_in_the_driver_before_any_actor(ray_local, tmp_path):
    """Today: a Ray actor-death message around "the capture-time store is damaged ... move it aside"."""
    from farm.service.actor import _running, get_service

    bad = damaged_file(tmp_path / "bad.sqlite")
    with pytest.raises(StoreCorruptError) as e:
        StatsStore(bad)
    damaged = str(e.value)
    for path, kind, want in ((tmp_path, ConfigError, f"store: {tmp_path} is a folder, not a capture-time store file"),
                             (bad, StoreCorruptError, damaged)):
        t0 = time.perf_counter()
        with pytest.raises(kind) as e:
            get_service(path, name="svc-refuses-driver")
        assert one_line(e.value) == want and time.perf_counter() - t0 < 5
        assert not _running("svc-refuses-driver")  # no actor was made
    with pytest.raises(ConfigError) as e:
        with open_client(SMALL, mode="ray", store=tmp_path):
            pass
    assert one_line(e.value) == f"store: {tmp_path} is a folder, not a capture-time store file"

    ro = tmp_path / "ro.sqlite"
    filled(ro, ((1, 1),))
    with immutable(ro):
        with pytest.raises(ConfigError) as e:
            get_service(ro, name="svc-refuses-driver")
        assert one_line(e.value).startswith(f"store: {ro} is read-only")
    assert not _running("svc-refuses-driver")


@pytest.mark.ray
def test_an_actor_dying_of_a_project_error_raises_its_line(ray_local, tmp_path, monkeypatch):
    """Where the driver cannot check the store (it runs on another node), the actor's death
    raises the project error it died of, not Ray's wrapper."""
    import farm.service.actor as actor
    import ray

    monkeypatch.setattr(actor, "_driver_sees_the_store", lambda: False)
    bad = damaged_file(tmp_path / "bad.sqlite")
    with pytest.raises(StoreCorruptError) as e:
        StatsStore(bad.resolve())
    damaged = str(e.value)
    for n, (path, kind, want) in enumerate((
            (bad, StoreCorruptError, damaged),
            (tmp_path, ConfigError, f"store: {tmp_path.resolve()} is a folder, not a capture-time store file"))):
        with pytest.raises(kind) as e:
            actor.get_service(path, name=f"svc-dies-{n}")
        assert one_line(e.value) == want and not isinstance(e.value, ray.exceptions.RayError)
