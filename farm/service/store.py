"""The service's persistent store: SQLite in WAL mode.

Why SQLite/WAL rather than Parquet: the service writes one small row per case,
often, from one process, while others may read; SQLite commits each row
atomically (a crash mid-write leaves the last committed state), readers never
block the writer in WAL mode, and it is one file in the standard library.

Every row carries a SHA-256 of every column a reader uses: "v2:" + the hash of the key
digest, settings digest, team sizes, key and value (v1 rows, without the prefix, carry
the hash of the key digest, key and value only; they are served when their other columns
agree with their key, see _columns_of). A row damaged on disk is reported and never
served (it is recomputed); a file that is not a sound SQLite database stops the store with
one clear line. A path that is a folder, or a store that must be written but cannot be, is
refused at once in one line (check_store_path), before any work.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sqlite3
import threading
import time
from pathlib import Path

from farm.core.errors import ConfigError, NotAStoreError, StoreCorruptError
from farm.service.keys import StatsKey
from workers import CaptureStats, InputError

log = logging.getLogger(__name__)

SCHEMA = """
CREATE TABLE IF NOT EXISTS stats (
    key TEXT PRIMARY KEY,
    settings TEXT NOT NULL,
    n_pursuers INTEGER NOT NULL,
    n_evaders INTEGER NOT NULL,
    key_json TEXT NOT NULL,
    value_json TEXT NOT NULL,
    checksum TEXT NOT NULL,
    created REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS stats_settings ON stats (settings);
"""


def _lenient_text(data: bytes) -> str:
    """A text column's bytes as text, a byte that is not UTF-8 replaced (U+FFFD)."""
    return data.decode("utf-8", errors="replace")


def _checksum(key: str, key_json: str, value_json: str) -> str:
    """A v1 row's checksum: key digest, key and value only."""
    return hashlib.sha256(f"{key}\n{key_json}\n{value_json}".encode()).hexdigest()


CHECKSUM_V2 = "v2:"


def _checksum_v2(key: str, settings: str, n_p: int, n_e: int, key_json: str, value_json: str) -> str:
    """A row's checksum (v2): every column a reader uses."""
    blob = f"{key}\n{settings}\n{n_p!r}\n{n_e!r}\n{key_json}\n{value_json}"
    return CHECKSUM_V2 + hashlib.sha256(blob.encode()).hexdigest()


class _StoredKey:
    """A stored key_json's dict where StatsKey.settings_digest wants a StatsKey (to_dict()
    is all it reads), so a row's settings digest is recomputed by the one formula."""

    def __init__(self, d: dict):
        self._d = d

    def to_dict(self) -> dict:
        """A copy of the stored key's dict."""
        return json.loads(json.dumps(self._d))


def _columns_of(key_json: str) -> tuple[str, str, int, int]:
    """(key digest, settings digest, n_p, n_e) as StatsStore.put writes them for this key_json."""
    d = json.loads(key_json)
    case = d["case"]
    return (hashlib.sha256(key_json.encode()).hexdigest(), StatsKey.settings_digest(_StoredKey(d)),
            case["n_pursuers"], case["n_evaders"])


def check_store_path(path: str | Path, *, write: bool = True) -> Path:
    """Refuse at once, in one line (ConfigError naming the path), a store path that no store
    can be opened at: a folder, or a path below a file; with write, also a store that cannot
    be written (the file, or the folder it lives or would be made in, is not writable: SQLite
    writes its -wal and -shm files next to it). Creates nothing; returns the path."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"store: {path} is a folder, not a capture-time store file", field="store")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"store: {path}: {folder} is a file, not a folder", field="store")
    if not write:
        return path
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"store: {path} is read-only (the file is not writable); "
                          "make it writable or name another store", field="store")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"store: {path} is read-only (its folder {folder} is not writable); "
                          "make it writable or name another store", field="store")
    return path


def check_store(path: str | Path) -> Path:
    """Everything StatsStore(path) would refuse, checked without writing: check_store_path,
    then, for an existing file, that it is a sound SQLite database (StoreCorruptError
    otherwise). For a caller that opens the store elsewhere (the service actor): its
    refusals come here, before any work, in one line."""
    path = check_store_path(path)
    if path.is_file() and path.stat().st_size > 0:
        try:
            StatsStore(path, read_only=True).close()
        except NotAStoreError:  # a sound SQLite file: opened for writing, it gets the store's table
            pass
    return path


def _read_only_error(path: Path, e: sqlite3.Error) -> ConfigError | None:
    """The one-line refusal of a store SQLite cannot write to, None for any other SQLite error."""
    if not str(getattr(e, "sqlite_errorname", "")).startswith("SQLITE_READONLY"):
        return None
    return ConfigError(f"store: {path} is read-only ({str(e).splitlines()[0]}); "
                       "make it writable or name another store", field="store")


STORE_ENV = "SWARM_FARM_STORE"


def default_store_path() -> Path:
    """The store used when none is named (an allocation env made without a client):
    $SWARM_FARM_STORE, else capture_times.sqlite in the user's cache folder
    ($XDG_CACHE_HOME/swarm-farm, by default ~/.cache/swarm-farm)."""
    if os.environ.get(STORE_ENV):
        return Path(os.environ[STORE_ENV])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "swarm-farm" / "capture_times.sqlite"


class StatsStore:
    """key digest -> CaptureStats, on disk. A row's value is CaptureStats.flat() as JSON
    (older rows, with a few more keys, read the same).

    Opening refuses at once, in one line: a path that is a folder (ConfigError), a store
    that cannot be written unless read_only (ConfigError: the file or its folder is not
    writable, or SQLite cannot write it, tried by a write that changes nothing), a damaged
    file (StoreCorruptError). Every reader (get, load_all, sizes, table) sees verified rows
    only (see rows())."""

    def __init__(self, path: str | Path, *, read_only: bool = False):
        self.path = check_store_path(path, write=not read_only)
        if not read_only:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise ConfigError(f"store: {self.path}: cannot make its folder ({e.strerror or e})",
                                  field="store") from None
        self.corrupt_rows: set[str] = set()
        self.older_rows: set[str] = set()  # rows of an older engine's layout: never served (their keys differ)
        self._lock = threading.Lock()
        self.db = None
        try:
            if read_only:
                self.db = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode=ro", uri=True,
                                          check_same_thread=False, isolation_level=None, timeout=30)
            else:
                self.db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None, timeout=30)
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute("PRAGMA synchronous=NORMAL")
            # A damaged byte may leave a text column that is not UTF-8: read it as text all the
            # same (the byte replaced), so that the row fails its checksum and is reported.
            self.db.text_factory = _lenient_text
            ok = self.db.execute("PRAGMA quick_check").fetchone()[0]
            if ok != "ok":
                raise sqlite3.DatabaseError(ok)
            if read_only:
                tables = {r[0] for r in self.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
                if "stats" not in tables:
                    raise NotAStoreError(f"{self.path}: not a capture-time store")
            else:
                self.db.executescript(SCHEMA)
                self.db.execute("DELETE FROM stats WHERE 0")  # a write that changes nothing: fails if read-only
        except NotAStoreError:
            self.db.close()
            raise
        except sqlite3.DatabaseError as e:
            if self.db is not None:
                self.db.close()
            refusal = _read_only_error(self.path, e)
            if refusal is not None:
                raise refusal from None
            raise StoreCorruptError(
                f"{self.path}: the capture-time store is damaged ({str(e).splitlines()[0]}); "
                "move it aside and its cases will be recomputed"
            ) from None

    def close(self) -> None:
        """Close the connection (the file stays as it is)."""
        self.db.close()

    _COLUMNS = "key, settings, n_pursuers, n_evaders, key_json, value_json, checksum"

    def _damaged(self, key: str, why: str) -> None:
        if key not in self.corrupt_rows:
            log.error("capture-time store %s: row %s %s; not served, will be recomputed", self.path, key, why)
        self.corrupt_rows.add(key)

    def _verified(self, key, settings, n_p, n_e, key_json, value_json, checksum) -> CaptureStats | None:
        """A row's value when every column a reader uses is verified, else None (a damaged
        row is reported in corrupt_rows, a row of an older engine's layout in older_rows).

        v2 rows: the checksum covers every column. v1 rows (the checksum covers the key
        digest, key and value) also need their settings digest and team
        sizes (and key digest) to be those of their key_json."""
        if isinstance(checksum, str) and checksum.startswith(CHECKSUM_V2):
            if _checksum_v2(key, settings, n_p, n_e, key_json, value_json) != checksum:
                self._damaged(key, "fails its checksum")
                return None
            v1 = False
        elif _checksum(key, key_json, value_json) != checksum:
            self._damaged(key, "fails its checksum")
            return None
        else:
            v1 = True
        try:
            value = CaptureStats.from_flat(json.loads(value_json))
        except (KeyError, InputError):  # a row of an older layout (engine 1.x: no escape statistics)
            if key not in self.older_rows:
                log.info("capture-time store %s: row %s is of an older engine's layout; left out", self.path, key)
            self.older_rows.add(key)
            return None
        if v1:
            try:
                agree = _columns_of(key_json) == (key, settings, n_p, n_e)
            except (ValueError, KeyError, TypeError):
                agree = False
            if not agree:
                self._damaged(key, "has settings or team-size columns that disagree with its key")
                return None
        return value

    def rows(self) -> list[tuple[str, str, int, int, CaptureStats]]:
        """(key digest, settings digest, n_p, n_e, value) of every verified row (damaged rows
        are reported and left out; so are rows of an older engine's layout)."""
        return [(row[0], row[1], row[2], row[3], value) for row, value in self._verified_rows()]

    def _verified_rows(self) -> list[tuple[tuple, CaptureStats]]:
        with self._lock:
            rows = self.db.execute(f"SELECT {self._COLUMNS} FROM stats").fetchall()
        return [(row, value) for row in rows if (value := self._verified(*row)) is not None]

    def get(self, key: StatsKey) -> CaptureStats | None:
        """The stored value of a key, None when it has no verified row."""
        digest = key.digest()
        with self._lock:
            row = self.db.execute(f"SELECT {self._COLUMNS} FROM stats WHERE key = ?", (digest,)).fetchone()
        return None if row is None else self._verified(*row)

    def put(self, key: StatsKey, value: CaptureStats) -> None:
        """Store a computed (never an estimated) value, in one atomic commit, and copy it
        from the write-ahead log into the database file (a checkpoint)."""
        if value.estimate is not None:
            raise ValueError("StatsStore.put: an estimate is never stored")
        digest = key.digest()
        key_json = json.dumps(key.to_dict(), sort_keys=True)
        value_json = json.dumps(value.flat(), sort_keys=True)
        n_p, n_e = key.sizes
        settings = key.settings_digest()
        with self._lock:
            self.db.execute(
                "INSERT OR REPLACE INTO stats VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (digest, settings, n_p, n_e, key_json, value_json,
                 _checksum_v2(digest, settings, n_p, n_e, key_json, value_json), time.time()),
            )
            # The row into the main file now, not at the last connection's close: the service
            # actor is killed with Ray, never closed, and a copy of the .sqlite file alone
            # (without its -wal) must hold every row. PASSIVE: never waits for a reader.
            self.db.execute("PRAGMA wal_checkpoint(PASSIVE)")

    def load_all(self) -> dict[str, CaptureStats]:
        """Every verified row: digest -> value (damaged rows are reported and left out)."""
        return {digest: value for digest, _, _, _, value in self.rows()}

    def table(self) -> list[dict]:
        """All verified rows with their keys, for `farm table show`."""
        return [{"key": json.loads(row[4]), "value": value} for row, value in self._verified_rows()]
