"""Optional experiment tracking: the `tracking:` block of training and experiment configs
(TrackingParams; its one tracker, MLflow: MlflowParams) and what both share (a tracking URI
checked and its MLflow experiment, open_experiment; MLflow's calls while a run goes on, Guard;
a config as MLflow params). TensorBoard (SB3's) stays on; MLflow is imported only when set.

    tracking:
      mlflow:
        tracking_uri: sqlite:///results/mlflow.db   # or http://host:5000, or a path (below)
        experiment: my-study                        # default: the config's name

A tracking_uri without a scheme is a local path: one ending in .db or .sqlite is an SQLite
store (sqlite:///<absolute path>), any other a folder store (file:<absolute path>, which
MLflow 3 opens only with MLFLOW_ALLOW_FILE_STORE=true). Tracking never changes a computed
number, nor a run's identity, nor whether a run finishes. docs/training.md and
docs/experiments.md say what is logged.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import socket
import warnings
from pathlib import Path
from urllib.parse import urlsplit

from pydantic import Field, field_validator

from farm.core.config import Strict
from farm.core.errors import ConfigError, SwarmFarmError

__all__ = ["MlflowParams", "TrackingParams", "TrackingWarning", "flat_params", "flattened", "param_text",
           "mlflow_client", "mlflow_experiment", "open_experiment", "check_tracking_uri", "Guard", "URI_FIELD",
           "quiet_tracker_logs"]

URI_FIELD = "tracking.mlflow.tracking_uri"
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+:")  # two letters at least: C:\ is a Windows path, not a scheme
_SQLITE_SUFFIXES = (".db", ".sqlite", ".sqlite3")
MAX_PARAM_LENGTH = 6000  # MLflow's longest param value
_HTTP = ("http", "https")
_SQL_SERVERS = {"postgresql": 5432, "postgres": 5432, "mysql": 3306, "mariadb": 3306, "mssql": 1433}
_MLFLOW_TABLES = {"experiments", "runs"}  # an SQLite file holding these is an MLflow store
PROBE_SECONDS = 5.0  # how long the check waits for a tracking server or database server to answer
# MLflow's HTTP settings (its public environment variables, read at each request) while a URI is
# checked: no retry, a short wait, so that a server that does not answer is refused at once
# (MLflow's defaults retry for minutes); and while a run goes on: a few retries, so that a server
# that went away costs a run seconds, not minutes, before tracking is turned off.
CHECK_HTTP = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0", "MLFLOW_HTTP_REQUEST_TIMEOUT": str(int(PROBE_SECONDS))}
RUN_HTTP = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1",
            "MLFLOW_HTTP_REQUEST_TIMEOUT": "15"}


class TrackingWarning(UserWarning):
    """MLflow failed while a run or an experiment went on: said once, in one line; the run (the
    experiment) goes on untracked and finishes as an untracked one would."""


class MlflowParams(Strict):
    """Where a run is logged in MLflow: tracking_uri (the tracking server or store: sqlite:///PATH,
    http(s)://HOST, a local path as the module doc says) and experiment (the MLflow experiment's
    name; None: the config's name)."""

    tracking_uri: str  # sqlite:///PATH.db, http(s)://HOST:PORT, or a local path (.db/.sqlite: SQLite; else a folder)
    experiment: str | None = Field(None, min_length=1, max_length=500)  # MLflow experiment; None: the config's name

    @field_validator("tracking_uri")
    @classmethod
    def _uri(cls, v: str) -> str:
        v = v.strip()
        if not v:
            raise ValueError("must be a tracking URI (sqlite:///PATH.db, http://HOST:PORT) or a local path, got ''")
        if _SCHEME.match(v):
            return _checked_scheme(v)
        path = Path(v).expanduser().resolve()
        return f"sqlite:///{path}" if path.suffix.lower() in _SQLITE_SUFFIXES else path.as_uri()

    @field_validator("experiment")
    @classmethod
    def _name(cls, v: str | None) -> str | None:
        if v is not None and not v.strip():
            raise ValueError(f"must be a non-empty experiment name, got {v!r}")
        return v


class TrackingParams(Strict):
    """A config's `tracking:` block: mlflow (MlflowParams; None: no MLflow, TensorBoard only)."""

    mlflow: MlflowParams | None = None  # where to log to MLflow; None: no MLflow (TensorBoard only)


def _checked_scheme(uri: str) -> str:
    """uri when its form can work: an http(s) URI names a host (without one MLflow retries without
    end), an SQLite one a file (an in-memory store keeps nothing); ValueError otherwise."""
    scheme = uri.split(":", 1)[0].lower()
    if scheme in _HTTP and not urlsplit(uri).hostname:
        raise ValueError(f"{uri} names no host; give {scheme}://HOST:PORT")
    if scheme == "sqlite" and _sqlite_path(uri) in (None, ":memory:"):
        raise ValueError(f"{uri} is an in-memory SQLite store, which keeps nothing; give sqlite:///PATH.db")
    return uri


def _sqlite_path(uri: str) -> str | None:
    """The database file of an sqlite: URI (relative to the working folder unless absolute), None
    for none (sqlite://: in memory)."""
    rest = uri.split(":", 1)[1].split("?", 1)[0]
    if not rest.startswith("///"):
        return None
    return rest[3:] or None


def shown(uri: str) -> str:
    """uri as a message may show it: a password in it (postgresql://user:secret@host/db) masked."""
    parts = urlsplit(uri)
    if parts.password:
        return uri.replace(f":{parts.password}@", ":***@", 1)
    return uri


def _refusal(uri: str, problem: str) -> ConfigError:
    return ConfigError(f"{URI_FIELD}: {shown(uri)} {problem}", field=URI_FIELD)


def reason(e: BaseException) -> str:
    """An exception of MLflow or of what it uses (SQLAlchemy, SQLite, requests) as one short line:
    the driver's own error under SQLAlchemy's wrapper, its first line, at most 300 characters."""
    inner = getattr(e, "orig", None) or e  # SQLAlchemy's DBAPIError wraps the driver's error
    if isinstance(inner, ImportError) and inner.name:
        return f"its database driver (the Python module {inner.name}) is not installed"
    socket_error = _innermost_os_error(e)
    if socket_error is not None and socket_error is not inner:  # an HTTP request's: its cause, not the pool's dump
        return f"its request failed: {socket_error.strerror or socket_error or type(socket_error).__name__}"
    message = getattr(inner, "message", None) if not isinstance(inner, OSError) else None
    text = str(message or inner).strip()
    first = text.splitlines()[0] if text else ""
    return " ".join(first.split())[:300].rstrip(".") or type(inner).__name__


def _innermost_os_error(e: BaseException) -> OSError | None:
    """The last OSError in e's chain of causes (a socket's timeout or refused connection under
    requests' and urllib3's wrappers), None without one."""
    found, seen = None, set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError):
            found = e
        e = e.__cause__ or e.__context__
    return found


@contextlib.contextmanager
def mlflow_http(settings: dict[str, str]):
    """MLflow's HTTP settings (CHECK_HTTP, RUN_HTTP: its environment variables, which it reads at
    each request) for the block only; the values before are put back after it."""
    before = {name: os.environ.get(name) for name in settings}
    os.environ.update(settings)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextlib.contextmanager
def refused(uri: str):
    """Any failure of MLflow (or of what it uses) in the block as one line naming
    tracking.mlflow.tracking_uri (ConfigError); the project's own errors pass as they are."""
    try:
        yield
    except SwarmFarmError:
        raise
    except Exception as e:  # noqa: BLE001 - SQLAlchemy's, SQLite's, requests', MLflow's: all one line
        raise ConfigError(f"{URI_FIELD}: MLflow cannot use {shown(uri)!r}: {reason(e)}", field=URI_FIELD) from None


def check_tracking_uri(params: MlflowParams, *, store=None) -> None:
    """Refuse, in one line naming tracking.mlflow.tracking_uri (ConfigError), before any work, a
    tracking URI that cannot work, without MLflow: an SQLite store that is the capture-time store
    (store: the run's or experiment's store file), a folder, a damaged SQLite file or one of other
    tables, one that cannot be written (the file, or the folder it is or would be made in, is
    read-only: SQLite writes its journal beside it); a database server (postgresql://,
    mysql://, mssql://) whose Python driver is not installed; a tracking server or database
    server where nothing answers within PROBE_SECONDS."""
    uri = params.tracking_uri
    scheme = uri.split(":", 1)[0].lower().split("+", 1)[0]
    if scheme == "sqlite":
        _check_sqlite(uri, store)
    elif scheme in _SQL_SERVERS:
        _check_driver(uri)
        parts = urlsplit(uri)
        if parts.hostname:
            _check_answers(uri, parts.hostname, parts.port or _SQL_SERVERS[scheme])
    elif scheme in _HTTP:
        parts = urlsplit(uri)
        if not _proxied(uri):
            _check_answers(uri, parts.hostname, parts.port or (443 if scheme == "https" else 80))


def _check_sqlite(uri: str, store) -> None:
    import sqlite3

    path = Path(_sqlite_path(uri) or "").expanduser().absolute()
    if store is not None and (path.resolve() == Path(store).expanduser().resolve()
                              or (path.exists() and Path(store).exists() and os.path.samefile(path, store))):
        raise _refusal(uri, "is the capture-time store's file; keep MLflow's runs in a file of their own "
                            "(say mlflow.db beside it)")
    if path.is_dir():
        raise _refusal(uri, f"names a folder ({path}), not an SQLite file")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise _refusal(uri, f"cannot be made: {folder} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise _refusal(uri, f"is read-only (its folder {folder} is not writable); make it writable or name "
                            f"another")
    if path.exists():
        if not os.access(path, os.R_OK | os.W_OK):
            raise _refusal(uri, "is read-only (the file is not writable); make it writable or name another")
        try:  # read-write: a hot journal left by a killed writer is rolled back here, as MLflow would
            db = sqlite3.connect(f"{path.as_uri()}?mode=rw", uri=True)
            try:
                tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            finally:
                db.close()
        except sqlite3.Error as e:
            raise _refusal(uri, f"is not a sound SQLite file ({reason(e)})") from None
        if tables and not _MLFLOW_TABLES <= tables:
            names = ", ".join(sorted(tables)[:3]) + (", ..." if len(tables) > 3 else "")
            raise _refusal(uri, f"holds tables that are not MLflow's ({names}); name a file of its own")


def _check_driver(uri: str) -> None:
    """The database server's Python driver, imported as SQLAlchemy (MLflow's) would import it."""
    try:
        from sqlalchemy.engine import make_url

        make_url(uri).get_dialect().import_dbapi()
    except ImportError as e:
        raise _refusal(uri, f"cannot be used: {reason(e)}") from None
    except Exception as e:  # noqa: BLE001 - SQLAlchemy's ArgumentError, NoSuchModuleError: one line
        raise _refusal(uri, f"is not a database URI SQLAlchemy knows ({reason(e)})") from None


def _proxied(uri: str) -> bool:
    """Whether requests (MLflow's HTTP client) reaches uri through a proxy ($HTTP_PROXY, ...):
    then the proxy, not the host, is what answers first."""
    from urllib.request import getproxies, proxy_bypass

    host = urlsplit(uri).hostname or ""
    return bool(getproxies()) and not proxy_bypass(host)


def _check_answers(uri: str, host: str, port: int) -> None:
    """A TCP connection to host:port within PROBE_SECONDS, or a refusal naming it."""
    try:
        with socket.create_connection((host, port), timeout=PROBE_SECONDS):
            pass
    except OSError as e:
        why = e.strerror or str(e) or type(e).__name__
        raise _refusal(uri, f"does not answer: nothing at {host}:{port} within {PROBE_SECONDS:g} s ({why})") from None


def open_experiment(params: MlflowParams, default_name: str, *, store=None):
    """(client, experiment id): the tracking URI checked (check_tracking_uri), an
    mlflow.tracking.MlflowClient of it and the MLflow experiment params name (default_name when it
    names none), created when missing; all before any work, with MLflow's HTTP retries off
    (CHECK_HTTP). ConfigError of one line naming tracking.mlflow.tracking_uri when it cannot
    work. Changes no process-wide MLflow setting."""
    check_tracking_uri(params, store=store)
    with mlflow_http(CHECK_HTTP):
        client = mlflow_client(params)
        return client, mlflow_experiment(client, params, default_name)


def mlflow_client(params: MlflowParams):
    """An mlflow.tracking.MlflowClient of params.tracking_uri (imports mlflow); changes no
    process-wide MLflow setting. ConfigError of one line naming tracking.mlflow.tracking_uri
    when MLflow cannot open the store."""
    from mlflow.tracking import MlflowClient

    with refused(params.tracking_uri):
        return MlflowClient(tracking_uri=params.tracking_uri)


def _artifact_location(uri: str) -> str | None:
    """Where a new experiment of an SQLite store keeps its artifacts: mlartifacts/ beside the
    database (MLflow's own default is ./mlruns in the working folder); None (the server's or
    store's choice) for any other store."""
    if uri.startswith("sqlite:///"):
        database = Path(uri[len("sqlite:///"):])
        return (database.resolve().parent / "mlartifacts").as_uri()
    return None


def mlflow_experiment(client, params: MlflowParams, default_name: str) -> str:
    """The id of the MLflow experiment params name (default_name when it names none), created
    when missing; ConfigError of one line naming tracking.mlflow.tracking_uri when MLflow
    cannot open the store or the experiment."""
    name = params.experiment or default_name
    with refused(params.tracking_uri):
        found = client.get_experiment_by_name(name)
        if found is not None:
            if found.lifecycle_stage == "deleted":
                raise ConfigError(f"tracking.mlflow.experiment: MLflow experiment {name!r} is deleted "
                                  f"(restore it, or name another)", field="tracking.mlflow.experiment")
            return found.experiment_id
        return client.create_experiment(name, artifact_location=_artifact_location(params.tracking_uri))


class Guard:
    """MLflow's calls while a run or an experiment goes on (tracking is meant to change nothing of
    it): a call that fails turns tracking off for the rest of it with one TrackingWarning (what:
    the run or the experiment, in the warning), never an error; a call after that is skipped.
    Calls run under RUN_HTTP. Tune pickles an experiment's logger, a Guard with it: a restored one
    is on again."""

    def __init__(self, what: str, on_off=None):
        self.what, self.off, self.on_off = what, False, on_off

    def __call__(self, doing: str, call, *args, **kwargs):
        """call(*args, **kwargs)'s value, or None when tracking is off or the call failed
        (doing: what it does, for the warning). The tracker's own loggers are quiet while it
        runs: its failure is said once, by the warning. When tracking is given up, on_off() is
        called, once, as quietly (ending the MLflow run FAILED where the store still takes it)."""
        if self.off:
            return None
        try:
            with mlflow_http(RUN_HTTP), quiet_tracker_logs():
                return call(*args, **kwargs)
        except Exception as e:  # noqa: BLE001 - any failure of the tracker: the run goes on
            self.off = True
            warnings.warn(f"tracking.mlflow: MLflow failed {doing} ({reason(e)}); {self.what} goes on untracked",
                          TrackingWarning, stacklevel=2)
            if self.on_off is not None:
                with contextlib.suppress(Exception), mlflow_http(RUN_HTTP), quiet_tracker_logs():
                    self.on_off()
            return None


TRACKER_LOGGERS = ("mlflow", "alembic", "sqlalchemy", "urllib3")  # the tracker's and its libraries' loggers


@contextlib.contextmanager
def quiet_tracker_logs():
    """The tracker's loggers (TRACKER_LOGGERS) silent for the block, their levels restored after:
    what they would print about a failure the project reports itself in one line."""
    import logging

    loggers = [logging.getLogger(name) for name in TRACKER_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def flattened(values: dict, sep: str = ".", prefix: str = "") -> dict:
    """Nested mappings flattened by sep ({"a": {"b": 1}} -> {"a.b": 1}), the leaves as they are
    (an empty mapping is a leaf)."""
    out = {}
    for key, value in values.items():
        name = f"{prefix}{sep}{key}" if prefix else str(key)
        if isinstance(value, dict) and value:
            out.update(flattened(value, sep, name))
        else:
            out[name] = value
    return out


def param_text(text: str) -> str:
    """text cut to MLflow's longest param value (ending in "..." when cut)."""
    return text if len(text) <= MAX_PARAM_LENGTH else text[: MAX_PARAM_LENGTH - 3] + "..."


def flat_params(values: dict) -> dict[str, str]:
    """Plain values (a config's, as JSON) as MLflow params: nested mappings by dotted key
    (env.grid_size), every leaf as text (strings as they are, others as JSON: null, [400, 300])."""
    return {key: param_text(value if isinstance(value, str) else json.dumps(value))
            for key, value in flattened(values).items()}
