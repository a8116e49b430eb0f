"""An experiment's folder: the one reader and writer of its files.

    experiment.json           the manifest: the config as given, its digest, every trial's key, point and seed
    trials/<trial>/run        the trial's training run folder (farm.alloc.training.runs)
    trials/<trial>/result.json the trial's row of trials.csv, written when it has finished
    trials.csv, summary.csv   the tables (farm.studies.experiments.tables)
    claims.csv, claims_seeds.csv, learning_curves.png
    tune/                     Ray Tune's experiment state

A trial counts as finished when its result.json exists. Readers of a damaged file get one
line (ResultsError naming the file), never a traceback. Below both the experiments that write
the folder (farm.studies.experiments) and the claims read over its seeds (farm.studies.claims).
"""

from __future__ import annotations

import json
from pathlib import Path

from farm.core.errors import ConfigError, ResultsError

__all__ = ["ExperimentFolder", "is_experiment", "read_manifest", "finished_trials", "MANIFEST", "RESULT", "TUNE_DIR"]

MANIFEST = "experiment.json"
RESULT = "result.json"
TUNE_DIR = "tune"


def _read_json(path: Path, what: str):
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ResultsError(f"{path}: unreadable {what} ({type(e).__name__})") from None


def write_json(path: Path, doc: dict) -> None:
    """Write doc as indented JSON, atomically (floats of numpy written as floats)."""
    from farm.core.output import atomic_write_bytes

    atomic_write_bytes(path, (json.dumps(doc, indent=2, default=float) + "\n").encode())


class ExperimentFolder:
    """One experiment's folder (see the module doc). path: the folder."""

    def __init__(self, path):
        self.path = Path(path)

    def file(self, name: str) -> Path:
        """The path of one of the experiment's files."""
        return self.path / name

    def trial_dir(self, key: str) -> Path:
        """trials/<key>: the trial's folder."""
        return self.path / "trials" / key

    def run_dir(self, key: str) -> Path:
        """trials/<key>/run: the trial's run folder."""
        return self.trial_dir(key) / "run"

    def result_path(self, key: str) -> Path:
        """trials/<key>/result.json."""
        return self.trial_dir(key) / RESULT

    def is_experiment(self) -> bool:
        """Whether the folder holds an experiment (its experiment.json)."""
        return self.file(MANIFEST).is_file()

    # ------------------------------------------------------------------ the manifest
    def check_for(self, digest: str) -> None:
        """ConfigError (one line naming out) when the folder holds another experiment (another
        digest), or files that are not an experiment's."""
        out = self.path
        if out.exists() and not out.is_dir():
            raise ConfigError(f"out: {out} exists and is not a folder", field="out")
        manifest = self.file(MANIFEST)
        if manifest.exists():
            try:
                doc = json.loads(manifest.read_text())
                found, name = doc["digest"], doc["name"]
            except (ValueError, KeyError, TypeError):
                raise ConfigError(f"out: {manifest} is damaged; choose another folder", field="out") from None
            if found != digest:
                raise ConfigError(f"out: {out} holds another experiment ({name}, config digest {found}, not "
                                  f"{digest}); choose another folder", field="out")
        elif out.exists() and any(out.iterdir()):
            raise ConfigError(f"out: {out} is not empty and holds no experiment ({MANIFEST}); choose another folder",
                              field="out")

    def write_manifest(self, doc: dict) -> None:
        """Write experiment.json once (an existing one, checked by check_for, stays)."""
        if self.file(MANIFEST).exists():
            return
        self.path.mkdir(parents=True, exist_ok=True)
        write_json(self.file(MANIFEST), doc)

    def read_manifest(self) -> dict:
        """experiment.json: {name, digest, config, store, fields (grid fields), trials: [{key,
        point, seed, values}]}; ResultsError (one line) when it is unreadable or not an experiment's."""
        path = self.file(MANIFEST)
        doc = _read_json(path, "experiment manifest")
        if not (isinstance(doc, dict) and isinstance(doc.get("trials"), list) and isinstance(doc.get("fields"), list)):
            raise ResultsError(f"{path}: not an experiment manifest (no trials or fields)")
        return doc

    # ------------------------------------------------------------------ the trials
    def finished(self, key: str) -> bool:
        """Whether the trial has finished (its result.json)."""
        return self.result_path(key).exists()

    def read_result(self, key: str) -> dict:
        """The trial's result.json (a row of trials.csv)."""
        return _read_json(self.result_path(key), "trial result")

    def write_result(self, key: str, result: dict) -> None:
        """Write the trial's result.json (its last step: the trial has finished)."""
        write_json(self.result_path(key), result)

    def finished_trials(self, manifest: dict) -> list[dict]:
        """The manifest's finished trials, in grid order: its entries {key, point, seed, values} with
        run (Path: the trial's run folder) and result (dict: its result.json, a row of trials.csv)."""
        return [{**t, "run": self.run_dir(t["key"]), "result": self.read_result(t["key"])}
                for t in manifest["trials"] if self.finished(t["key"])]

    # ------------------------------------------------------------------ the tables
    def write_tables(self, trials, summary) -> list[Path]:
        """trials.csv and summary.csv."""
        from farm.core.output import write_table

        return [write_table(trials, self.path / "trials", "csv"), write_table(summary, self.path / "summary", "csv")]


def is_experiment(folder) -> bool:
    """Whether folder holds an experiment (its experiment.json)."""
    return ExperimentFolder(folder).is_experiment()


def read_manifest(folder) -> dict:
    """ExperimentFolder(folder).read_manifest()."""
    return ExperimentFolder(folder).read_manifest()


def finished_trials(folder, manifest: dict) -> list[dict]:
    """ExperimentFolder(folder).finished_trials(manifest)."""
    return ExperimentFolder(folder).finished_trials(manifest)
