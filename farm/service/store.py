"""The service's persistent store: SQLite in WAL mode.

Why SQLite/WAL rather than Parquet: the service writes one small row per case,
often, from one process, while others may read; SQLite commits each row
atomically (a crash mid-write leaves the last committed state), readers never
block the writer in WAL mode, and it is one file in the standard library.
Every row carries a SHA-256 of its key and value: a row damaged on disk is
reported and never served (it is recomputed); a file that is not a sound SQLite
database stops the store with one clear line.
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

from workers import CaptureStats, InputError

from farm.errors import NotAStoreError, StoreCorruptError
from farm.service.keys import StatsKey

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


def _checksum(key: str, key_json: str, value_json: str) -> str:
    return hashlib.sha256(f"{key}\n{key_json}\n{value_json}".encode()).hexdigest()


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
    (rows written before CaptureStats, with a few more keys, read the same)."""

    def __init__(self, path: str | Path, *, read_only: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.corrupt_rows: set[str] = set()
        self.older_rows: set[str] = set()  # rows of an older engine's layout: never served (their keys differ)
        self._lock = threading.Lock()
        try:
            if read_only:
                self.db = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode=ro", uri=True,
                                          check_same_thread=False, isolation_level=None, timeout=30)
            else:
                self.db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None, timeout=30)
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute("PRAGMA synchronous=NORMAL")
            ok = self.db.execute("PRAGMA quick_check").fetchone()[0]
            if ok != "ok":
                raise sqlite3.DatabaseError(ok)
            if read_only:
                tables = {r[0] for r in self.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
                if "stats" not in tables:
                    raise NotAStoreError(f"{self.path}: not a capture-time store")
            else:
                self.db.executescript(SCHEMA)
        except NotAStoreError:
            self.db.close()
            raise
        except sqlite3.DatabaseError as e:
            raise StoreCorruptError(
                f"{self.path}: the capture-time store is damaged ({str(e).splitlines()[0]}); "
                "move it aside and its cases will be recomputed"
            ) from None

    def close(self) -> None:
        """Close the connection (the file stays as it is)."""
        self.db.close()

    def _row_value(self, key, key_json, value_json, checksum) -> CaptureStats | None:
        if _checksum(key, key_json, value_json) != checksum:
            if key not in self.corrupt_rows:
                log.error("capture-time store %s: row %s fails its checksum; not served, will be recomputed",
                          self.path, key)
            self.corrupt_rows.add(key)
            return None
        try:
            return CaptureStats.from_flat(json.loads(value_json))
        except (KeyError, InputError):  # a row of an older layout (engine 1.x: no escape statistics)
            if key not in self.older_rows:
                log.info("capture-time store %s: row %s is of an older engine's layout; left out", self.path, key)
            self.older_rows.add(key)
            return None

    def get(self, key: StatsKey) -> CaptureStats | None:
        """The stored value of a key, None when it has no sound row."""
        digest = key.digest()
        with self._lock:
            row = self.db.execute("SELECT key, key_json, value_json, checksum FROM stats WHERE key = ?",
                                  (digest,)).fetchone()
        return None if row is None else self._row_value(*row)

    def put(self, key: StatsKey, value: CaptureStats) -> None:
        """Store a computed (never an estimated) value, in one atomic commit."""
        if value.estimate is not None:
            raise ValueError("StatsStore.put: an estimate is never stored")
        digest = key.digest()
        key_json = json.dumps(key.to_dict(), sort_keys=True)
        value_json = json.dumps(value.flat(), sort_keys=True)
        n_p, n_e = key.sizes
        with self._lock:
            self.db.execute(
                "INSERT OR REPLACE INTO stats VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (digest, key.settings_digest(), n_p, n_e, key_json, value_json,
                 _checksum(digest, key_json, value_json), time.time()),
            )

    def load_all(self) -> dict[str, CaptureStats]:
        """Every sound row: digest -> value (damaged rows are reported and left out)."""
        with self._lock:
            rows = self.db.execute("SELECT key, key_json, value_json, checksum FROM stats").fetchall()
        out = {}
        for row in rows:
            value = self._row_value(*row)
            if value is not None:
                out[row[0]] = value
        return out

    def sizes(self) -> list[tuple[str, str, int, int]]:
        """(key digest, settings digest, n_p, n_e) of every row, without reading the values."""
        with self._lock:
            return self.db.execute("SELECT key, settings, n_pursuers, n_evaders FROM stats").fetchall()

    def table(self) -> list[dict]:
        """All sound rows with their keys, for `farm table show`."""
        with self._lock:
            rows = self.db.execute("SELECT key, key_json, value_json, checksum FROM stats").fetchall()
        out = []
        for row in rows:
            value = self._row_value(*row)
            if value is not None:
                out.append({"key": json.loads(row[1]), "value": value})
        return out
