"""Writing result tables to disk atomically (a crash never leaves half a file)."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

import pandas as pd

from farm.core.errors import ConfigError

__all__ = ["FORMATS", "atomic_write_bytes", "write_table", "check_writable_folder", "check_writable_file"]

FORMATS = ("csv", "parquet")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write data to path through a temporary file in the same folder, fsynced, renamed
    over path, the folder fsynced: a crash leaves the old file or the new one. The file
    is created with mode 0666 less the process's umask, as open() would make it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)  # left only when the rename did not happen
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)  # the rename itself survives a crash
    finally:
        os.close(dir_fd)


def write_table(df: pd.DataFrame, stem: Path, fmt: str, metadata: dict[str, str] | None = None) -> Path:
    """Write df to stem.csv or stem.parquet atomically; returns the path. metadata: key-value
    pairs kept in a Parquet file's schema (pyarrow.parquet.read_schema(path).metadata)."""
    if fmt not in FORMATS:
        raise ValueError(f"format: must be one of {', '.join(FORMATS)}, got {fmt!r}")
    path = Path(f"{stem}.{fmt}")
    if fmt == "csv":
        data = df.to_csv(index=False).encode()
    else:
        import io

        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pandas(df, preserve_index=False)
        if metadata:
            table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                                   **{k.encode(): v.encode() for k, v in metadata.items()}})
        buf = io.BytesIO()
        pq.write_table(table, buf)
        data = buf.getvalue()
    atomic_write_bytes(path, data)
    return path


def _writable_folder_at(path: Path, start: Path, field: str) -> None:
    """Refuse path (ConfigError naming field) when the nearest existing folder at or above
    start is a file or cannot be written into (os.access: a read-only folder, chattr +i)."""
    folder = start
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"{field}: {path}: {folder} is a file, not a folder", field=field)
    if not os.access(folder, os.W_OK | os.X_OK):
        where = "it is" if folder == path else f"its folder {folder} is"
        raise ConfigError(f"{field}: {path} cannot be written ({where} read-only); make it writable or "
                          f"choose another", field=field)


def check_writable_folder(path, field: str) -> Path:
    """Refuse at once, in one line (ConfigError naming field), a folder that results cannot be
    written into: a path that is a file or lies below one, or whose nearest existing folder is
    not writable (a read-only --out, or one under a read-only parent), so that no work is done
    only to be lost at the end. Creates nothing; returns path as a Path."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{field}: {path} exists and is not a folder", field=field)
    _writable_folder_at(path, path, field)
    return path


def check_writable_file(path, field: str) -> Path:
    """Refuse at once, in one line (ConfigError naming field), a file path that cannot be
    written: a folder, a read-only file, or a file whose folder cannot be written into (as
    check_writable_folder), so that a figure or page is not computed only to be lost.
    Creates nothing; returns path as a Path."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{field}: {path} is a folder, not a file to write", field=field)
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"{field}: {path} cannot be written (it is read-only); make it writable or "
                          f"choose another", field=field)
    _writable_folder_at(path, path.parent, field)
    return path
