"""Optional experiment tracking: the `tracking:` block of training and experiment configs
(TrackingParams; its one tracker, MLflow: MlflowParams) and what both share (the MLflow
experiment a config logs into, a config flattened into MLflow params). TensorBoard (SB3's, in
every run folder) stays on; MLflow is used, and imported, only when `tracking.mlflow` is set.

    tracking:
      mlflow:
        tracking_uri: sqlite:///results/mlflow.db   # or http://host:5000, or a path (below)
        experiment: my-study                        # default: the config's name

A tracking_uri without a scheme is a local path: one ending in .db or .sqlite is an SQLite
store (sqlite:///<absolute path>), any other a folder store (file:<absolute path>, which
MLflow 3 opens only with MLFLOW_ALLOW_FILE_STORE=true). Tracking never changes a computed
number, nor a run's identity: a run resumed with tracking turned on (or off) is the same run.
docs/training.md and docs/experiments.md say what is logged.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from pydantic import Field, field_validator

from farm.core.config import Strict
from farm.core.errors import ConfigError

__all__ = ["MlflowParams", "TrackingParams", "flat_params", "flattened", "param_text", "mlflow_client", "mlflow_experiment", "URI_FIELD"]

URI_FIELD = "tracking.mlflow.tracking_uri"
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+:")  # two letters at least: C:\ is a Windows path, not a scheme
_SQLITE_SUFFIXES = (".db", ".sqlite", ".sqlite3")
MAX_PARAM_LENGTH = 6000  # MLflow's longest param value


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
            return v
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


def mlflow_client(params: MlflowParams):
    """An mlflow.tracking.MlflowClient of params.tracking_uri (imports mlflow); changes no
    process-wide MLflow setting. ConfigError of one line naming tracking.mlflow.tracking_uri
    when MLflow cannot open the store."""
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    try:
        return MlflowClient(tracking_uri=params.tracking_uri)
    except (MlflowException, OSError) as e:  # OSError: an SQLite store's folder that cannot be made
        raise ConfigError(f"{URI_FIELD}: MLflow cannot use {params.tracking_uri!r}: {_first_sentence(e)}",
                          field=URI_FIELD) from None


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
    from mlflow.exceptions import MlflowException

    name = params.experiment or default_name
    try:
        found = client.get_experiment_by_name(name)
        if found is not None:
            if found.lifecycle_stage == "deleted":
                raise ConfigError(f"tracking.mlflow.experiment: MLflow experiment {name!r} is deleted "
                                  f"(restore it, or name another)", field="tracking.mlflow.experiment")
            return found.experiment_id
        return client.create_experiment(name, artifact_location=_artifact_location(params.tracking_uri))
    except (MlflowException, OSError) as e:  # OSError: an SQLite store's folder that cannot be made
        raise ConfigError(f"{URI_FIELD}: MLflow cannot use {params.tracking_uri!r}: {_first_sentence(e)}",
                          field=URI_FIELD) from None


def _first_sentence(e: Exception) -> str:
    text = " ".join(str(e).split())
    return text.split(". ")[0].rstrip(".")[:300] or type(e).__name__


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
