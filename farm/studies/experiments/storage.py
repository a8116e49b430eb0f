"""Where an experiment lives: a local folder, or a folder of a filesystem pyarrow names by URI
(SCHEMES: ``s3://bucket/path``, ``gs://bucket/path``, ``hdfs://…``, ``file://…``), the storage Ray
Tune itself writes its experiment state and checkpoints to.

ExperimentStorage says what is staged where: a local folder needs a shared file system on a
cluster, a URI none. ExperimentStorage.check refuses, before Ray starts, a storage that cannot
work; a storage failing while the experiment runs is a StorageError naming it and what is missing.

Credentials and endpoints are pyarrow's (and so Tune's): the standard environment variables
(AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_ENDPOINT_URL, …, set on every node) or the URI's
query (``s3://bucket/x?endpoint_override=host:9000&scheme=http``).
"""

from __future__ import annotations

import contextlib
import json
import posixpath
import re
import shutil
import sys
import tempfile
from pathlib import Path

from farm.core.errors import ConfigError, StorageError, SwarmFarmError
from farm.studies.experiment_folder import MANIFEST, RESULT, ExperimentFolder

__all__ = ["ExperimentStorage", "is_uri", "restore_run", "drop_stale_run", "checkpoint_run", "RUN_IN_CHECKPOINT",
           "NOT_UPLOADED", "SCHEMES", "PROBE_SECONDS"]

RUN_IN_CHECKPOINT = "run"  # a Tune checkpoint's copy of the run folder
NOT_UPLOADED = ("checkpoints", "pretrain")  # a finished trial's run folder keeps its state in Tune's checkpoints
# The URI schemes an experiment may live at: pyarrow's filesystems that Ray's workers can be handed
# (they pickle); pyarrow's mock:// does not.
SCHEMES = ("s3", "gs", "gcs", "abfs", "abfss", "hdfs", "viewfs", "file")
_BUCKETS = ("s3", "gs", "gcs", "abfs", "abfss")  # the path's first part is a bucket (a container)
_FLAT = ("s3", "gcs")  # pyarrow type names of stores whose folders need not exist before a file is written in them
PROBE_SECONDS = 5.0  # how long the check before Ray waits for object storage to answer a request
_MISSING = ("NO_SUCH_KEY", "NoSuchKey", "NOT_FOUND", "Path does not exist", "No such file")
_UNREACHABLE = ("NETWORK_CONNECTION", "Could not connect", "Could not resolve", "timed out", "Timeout", "UNAVAILABLE")
_CREDENTIALS = ("ACCESS_DENIED", "AccessDenied", "INVALID_ACCESS_KEY_ID", "SIGNATURE_DOES_NOT_MATCH", "OAuth2",
                "PERMISSION_DENIED", "UNAUTHENTICATED", "credentials", "Forbidden")
_HINTS = {"s3": "AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, or a profile in ~/.aws",
          "gcs": "GOOGLE_APPLICATION_CREDENTIALS, or gcloud auth application-default login"}


def is_uri(out) -> bool:
    """Whether out names a folder of a pyarrow filesystem by URI (``scheme://…``), not a local path."""
    return isinstance(out, str) and "://" in out


class ExperimentStorage:
    """An experiment's storage: out, a local folder (str or Path) or a URI; field: what names it
    in messages. ConfigError (one line, naming field) for a URI of a scheme not in SCHEMES, one
    pyarrow cannot open or one that names no bucket.

    With a local folder nothing is staged: the driver reads and writes ExperimentFolder(out) and
    every trial trains in its run folder there (a cluster then needs that folder on a shared file
    system). With a URI the experiment needs no shared file system:

    - a trial trains in a run folder in its node's temporary space (ExperimentStorage.run_dir);
      everything its resume needs travels in its Tune checkpoints, which Tune uploads
      to the storage (farm.studies.experiments.tune.TuneReport, and PretrainReport for each saved
      pretraining iteration), and a restarted trial, on whatever node, writes its run folder again
      from its last one (restore_run);
    - a finished trial uploads its run folder (without checkpoints/ and pretrain/: the state
      lives in Tune's checkpoints) and then its result.json to trials/<key>/, and removes its
      local folder;
    - the driver stages the experiment in a temporary local folder: it downloads the manifest and
      the finished trials, writes the tables, claims and figures there with the same code as for a
      local folder, and uploads them.
    """

    def __init__(self, out, *, field: str = "out"):
        # a local folder by its absolute path: trials run in Tune's own working folders, where a
        # relative one would name another place than the driver's
        self.uri = str(out) if is_uri(out) else str(Path(out).resolve())
        self.field = field  # what names it in messages: --out, or a config's field
        if is_uri(out):
            from pyarrow import fs

            scheme = out.split("://", 1)[0].lower()
            if scheme not in SCHEMES:
                raise ConfigError(f"{field}: {out}: {scheme}:// is not a storage an experiment can live in (a local "
                                  f"folder, or {', '.join(f'{s}://' for s in SCHEMES)})", field=field)
            try:
                self.fs, self.root = fs.FileSystem.from_uri(out)
            except Exception as e:  # pyarrow's ArrowInvalid, OSError of the filesystem's client
                raise ConfigError(f"{field}: cannot open {out}: {_first_line(e)}", field=field) from None
            self.root = self.root.rstrip("/")
            if scheme in _BUCKETS and not self.root.split("/")[0]:
                raise ConfigError(f"{field}: {out} names no bucket (it would be the root of every bucket); give "
                                  f"{scheme}://BUCKET/FOLDER", field=field)
            self.local = self.folder = None
        else:
            self.fs, self.local = None, Path(out).resolve()
            self.root = str(self.local)
            self.folder = ExperimentFolder(self.local)  # a local experiment: every method is its folder's

    def __repr__(self) -> str:
        return f"ExperimentStorage({self.uri!r})"

    # ------------------------------------------------------------------ before Ray
    def check(self) -> None:
        """Refuse, in one line (ConfigError, field out), before Ray starts, a URI storage that
        cannot work: a filesystem that does not pickle (Ray's workers could not be handed it), one
        that does not answer within PROBE_SECONDS (a bounded request: pyarrow's timeouts and
        retries of S3 and GCS), that refuses the credentials or finds none, or whose bucket does
        not exist; a file:// folder that cannot be written. A file:// folder is made (with its
        parents: such a filesystem, unlike object storage, needs its folders). A local folder:
        nothing (the caller checks it is writable)."""
        if self.local is not None:
            return
        import pickle

        from pyarrow import fs

        try:
            pickle.dumps(self.fs)
        except Exception as e:  # noqa: BLE001 - pyarrow's TypeError, or any a filesystem's pickling raises
            raise ConfigError(f"{self.field}: {self.uri}: its filesystem ({self.fs.type_name}) cannot be handed to "
                              f"Ray's workers: it does not pickle ({_first_line(e)})", field=self.field) from None
        if self.fs.type_name == "local":
            from farm.core.output import check_writable_folder

            check_writable_folder(self.root, self.field)
            with self._failing("making its folder", refuse=True):
                self.fs.create_dir(self.root, recursive=True)
            return
        probe = _bounded(self.fs)
        bucket = self.root.split("/")[0]
        with self._failing("reaching it", refuse=True):
            if probe.get_file_info(self.root).type != fs.FileType.NotFound or self.fs.type_name not in _FLAT:
                return
        try:
            found = probe.get_file_info(bucket).type != fs.FileType.NotFound
        except OSError:  # credentials that may read objects but not the bucket's own metadata: not known
            return
        if not found:
            raise ConfigError(f"{self.field}: {self.uri}: bucket {bucket!r} does not exist; make it first, or name "
                              f"another", field=self.field)

    @contextlib.contextmanager
    def _failing(self, doing: str, refuse: bool = False):
        """An error of the filesystem in the block (pyarrow's OSError, ArrowException) as one line
        naming the storage and what it was doing (a ConfigError of field out with refuse, before
        Ray; else a StorageError): an object missing, a store that does not answer, credentials
        refused or missing, else the error's first line."""
        from pyarrow import ArrowException

        try:
            yield
        except SwarmFarmError:
            raise
        except (OSError, ArrowException) as e:
            problem = _storage_problem(e, self.fs.type_name)
            if refuse:
                raise ConfigError(f"{self.field}: {self.uri}: {doing}: {problem}", field=self.field) from None
            raise StorageError(f"{self.field}: {self.uri}: {doing}: {problem}") from None

    def _parents(self, *paths: str) -> None:
        """Make the folders of paths, on a filesystem that needs them (not object storage)."""
        if self.fs.type_name in _FLAT:
            return
        for folder in sorted({posixpath.dirname(p) for p in paths}):
            self.fs.create_dir(folder, recursive=True)

    def _path(self, *parts: str) -> str:
        return posixpath.join(self.root, *parts)

    def where(self, name: str):
        """A top-level file's place: a Path in a local folder, else its URI (for messages)."""
        if self.local is not None:
            return self.local / name
        return f"{self.uri.split('?')[0].rstrip('/')}/{name}"

    # ------------------------------------------------------------------ Tune
    def tune_storage(self) -> tuple[str, object]:
        """(storage_path, storage_filesystem) for Tune's RunConfig and Tuner.restore."""
        return self.root, self.fs

    # ------------------------------------------------------------------ the experiment
    def _info(self, *parts: str):
        return self.fs.get_file_info(self._path(*parts))

    def _exists(self, *parts: str) -> bool:
        from pyarrow import fs

        return self._info(*parts).type != fs.FileType.NotFound

    def check_for(self, digest: str) -> None:
        """ExperimentFolder.check_for on the storage: ConfigError (one line, field out) when it
        holds another experiment or files that are not an experiment's."""
        if self.local is not None:
            self.folder.check_for(digest)
            return
        with self._failing("reading what it holds", refuse=True):
            self._check_for(digest)

    def _check_for(self, digest: str) -> None:
        from pyarrow import fs

        if self._info().type == fs.FileType.File:
            raise ConfigError(f"{self.field}: {self.uri} exists and is not a folder", field=self.field)
        if self._exists(MANIFEST):
            with tempfile.TemporaryDirectory(prefix="farm-check-") as stage:
                self._download(MANIFEST, Path(stage) / MANIFEST)
                folder = ExperimentFolder(stage)
                try:
                    folder.check_for(digest)
                except ConfigError as e:
                    raise ConfigError(str(e).replace(stage, self.uri), field=self.field) from None
        elif self._info().type == fs.FileType.Directory and self.fs.get_file_info(
                fs.FileSelector(self._path(), recursive=False)):
            raise ConfigError(f"{self.field}: {self.uri} is not empty and holds no experiment ({MANIFEST}); choose "
                              f"another folder", field=self.field)

    def write_manifest(self, doc: dict) -> None:
        """Write experiment.json once (an existing one stays)."""
        if self.local is not None:
            self.folder.write_manifest(doc)
            return
        with self._failing(f"writing {MANIFEST}", refuse=True):
            if not self._exists(MANIFEST):
                self._write_bytes((json.dumps(doc, indent=2, default=float) + "\n").encode(), MANIFEST)

    def finished(self, key: str) -> bool:
        """Whether the trial has finished (its result.json)."""
        if self.local is not None:
            return self.folder.finished(key)
        with self._failing(f"looking for trials/{key}/{RESULT}"):
            return self._exists("trials", key, RESULT)

    def read_result(self, key: str) -> dict:
        """The trial's result.json."""
        if self.local is not None:
            return self.folder.read_result(key)
        with self._failing(f"reading trials/{key}/{RESULT}"), self.fs.open_input_stream(
                self._path("trials", key, RESULT)) as f:
            return json.loads(f.read())

    def write_result(self, key: str, result: dict) -> None:
        """Write the trial's result.json (its last step: the trial has finished)."""
        if self.local is not None:
            self.folder.write_result(key, result)
            return
        with self._failing(f"writing trials/{key}/{RESULT}"):
            self._write_bytes((json.dumps(result, indent=2, default=float) + "\n").encode(), "trials", key, RESULT)

    def run_dir(self, key: str) -> Path:
        """Where the trial trains: its run folder in a local experiment, else a folder of the
        node's temporary space named by the storage and the trial (the same on a restart on
        the same node, so that one goes on from the folder when it is as recent as the
        checkpoint), removed once the trial has uploaded its results (finish)."""
        if self.local is not None:
            return self.folder.run_dir(key)
        import hashlib

        where = hashlib.sha256(self.uri.encode()).hexdigest()[:16]
        return Path(tempfile.gettempdir()) / "swarm-farm-trials" / f"{where}-{key}" / "run"

    def finish(self, key: str, result: dict, run: Path) -> None:
        """A trial's last step: in object storage, upload its run folder to trials/<key>/run
        (without NOT_UPLOADED), then write its result.json (the trial has finished), then
        remove the local folder; in a local experiment, write its result.json."""
        if self.local is not None:
            self.write_result(key, result)
            return
        from pyarrow import fs

        files = [p.relative_to(run) for p in sorted(Path(run).rglob("*")) if p.is_file()]
        files = [rel for rel in files if rel.parts[0] not in NOT_UPLOADED]
        with self._failing(f"uploading trial {key}'s run folder to trials/{key}/run"):
            self._parents(*(self._path("trials", key, "run", *rel.parts) for rel in files))
            for rel in files:
                fs.copy_files(str(run / rel), self._path("trials", key, "run", *rel.parts),
                              destination_filesystem=self.fs)
        self.write_result(key, result)
        shutil.rmtree(run.parent, ignore_errors=True)

    # ------------------------------------------------------------------ the driver's stage
    @contextlib.contextmanager
    def staged(self):
        """The experiment as a local folder for the driver: the folder itself, or (a URI) a
        temporary one holding the manifest, removed at the end. stage_results fills it with
        the finished trials, publish uploads what the driver wrote."""
        if self.local is not None:
            yield self.local
            return
        with tempfile.TemporaryDirectory(prefix="farm-experiment-") as stage:
            stage = Path(stage)
            with self._failing(f"reading {MANIFEST}"):
                if not self._exists(MANIFEST):  # run_experiment wrote it first
                    raise StorageError(f"{self.field}: {self.uri}: {MANIFEST} is missing: the experiment's objects "
                                       f"were deleted while it ran; run it again")
                self._download(MANIFEST, stage / MANIFEST)
            yield stage

    def stage_results(self, stage: Path, keys: list[str]) -> None:
        """Download the finished trials among keys (result.json and run folder) into stage."""
        if self.local is not None:
            return
        from pyarrow import fs

        for key in keys:
            if self.finished(key):
                (stage / "trials" / key).mkdir(parents=True, exist_ok=True)
                with self._failing(f"downloading trial {key} (trials/{key})"):
                    fs.copy_files(self._path("trials", key), str(stage / "trials" / key), source_filesystem=self.fs)

    def publish(self, stage: Path, names) -> None:
        """Upload the driver's files (top-level names in stage; a missing one is skipped)."""
        if self.local is not None:
            return
        from pyarrow import fs

        for name in names:
            if (stage / name).is_file():
                with self._failing(f"uploading {name}"):
                    self._parents(self._path(name))
                    fs.copy_files(str(stage / name), self._path(name), destination_filesystem=self.fs)

    def _download(self, name: str, to: Path) -> None:
        from pyarrow import fs

        fs.copy_files(self._path(name), str(to), source_filesystem=self.fs)

    def _write_bytes(self, data: bytes, *parts: str) -> None:
        self.fs.create_dir(posixpath.dirname(self._path(*parts)), recursive=True)
        with self.fs.open_output_stream(self._path(*parts)) as f:
            f.write(data)


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def _storage_problem(e: BaseException, type_name: str) -> str:
    """What a filesystem's error says, in a few words: the object is missing, the storage does not
    answer, the credentials are refused or missing (with where pyarrow looks for them), else the
    error's first line; without a request id."""
    text = re.sub(r"\s*[;,.]?\s*(Request ID|request id|x-amz-request-id)\b.*$", "", _first_line(e))
    text = text.split(" error_info=")[0][:300]  # GCS's status repeats itself in its error_info
    if any(m in text for m in _CREDENTIALS):  # before the rest: GCS says UNAVAILABLE when it has none
        hint = _HINTS.get(type_name)
        return f"credentials refused or missing ({text})" + (f"; set {hint}" if hint else "")
    if isinstance(e, FileNotFoundError) or any(m in text for m in _MISSING):
        return f"not found ({text}); were its objects deleted while the experiment ran?"
    if any(m in text for m in _UNREACHABLE):
        return f"no answer within {PROBE_SECONDS:g} s ({text})"
    return text


def _bounded(filesystem):
    """A copy of filesystem whose requests give up within about PROBE_SECONDS (S3: connect and
    request timeouts, one attempt; GCS: a retry time limit); another filesystem as it is."""
    import datetime

    from pyarrow import fs

    if isinstance(filesystem, fs.S3FileSystem):
        options = filesystem.__reduce__()[1][0]  # its settings, as pickling carries them
        return fs.S3FileSystem(**{**options, "connect_timeout": PROBE_SECONDS / 2, "request_timeout": PROBE_SECONDS,
                                  "retry_strategy": fs.AwsStandardS3RetryStrategy(max_attempts=1)})
    if isinstance(filesystem, fs.GcsFileSystem):
        options = filesystem.__reduce__()[1][0]
        return fs.GcsFileSystem(**{**options, "retry_time_limit": datetime.timedelta(seconds=PROBE_SECONDS / 2)})
    return filesystem


def checkpoint_run(run: Path, steps: int | None, to: Path) -> None:
    """Copy a run folder into to/RUN_IN_CHECKPOINT as a Tune checkpoint holds it: every file but
    the checkpoints other than the one of `steps` (its model, replay buffer and RunState; steps
    None: a pretraining iteration's checkpoint, none of them) and the pretraining iterations
    other than the newest (each holds the labels of every iteration before it)."""
    from farm.alloc.training.dagger.loop import iteration_file, saved_iterations
    from farm.alloc.training.runs import checkpoint_files

    keep = set() if steps is None else {p.name for p in checkpoint_files(run, steps)}
    newest = {iteration_file(run, i).name for i in saved_iterations(run)[:1]}

    def ignore(folder, names):
        if Path(folder) == run / "checkpoints":
            return [n for n in names if n not in keep]
        if Path(folder) == run / "pretrain":
            return [n for n in names if n.startswith("iteration_") and n not in newest]
        return []

    shutil.copytree(run, to / RUN_IN_CHECKPOINT, ignore=ignore)


def _progress_here(run: Path, replay_buffer: bool) -> tuple[int, int] | None:
    """How far a run folder is: (1, steps) of its latest whole checkpoint, else (0, i) of its
    newest saved pretraining iteration i, else None; ordered as training goes."""
    from farm.alloc.training.dagger.loop import saved_iterations
    from farm.alloc.training.runs import latest_checkpoint

    if not run.exists():
        return None
    last = latest_checkpoint(run, replay_buffer=replay_buffer)
    if last is not None:
        return 1, last[1]
    iterations = saved_iterations(run)
    return (0, iterations[0]) if iterations else None


def _steps(progress: tuple[int, int] | None) -> int | None:
    return None if progress is None else (progress[1] if progress[0] == 1 else 0)


def drop_stale_run(storage: ExperimentStorage, run, config) -> bool:
    """Before a trial of an experiment in object storage trains: remove its run folder in the
    node's temporary space when that folder is not this trial's (a run of another config left by
    an earlier experiment at the same URI, or a folder whose config.yaml cannot be read). The
    folder is only a copy of the state the trial's Tune checkpoints hold, so nothing of this
    experiment is lost; kept, it would refuse the trial or resume it from another run. run: a
    RunFolder; config: the trial's TrainConfig. Returns whether it removed the folder. A local
    experiment's run folder is its record and is never removed here (train refuses another
    config's in one line)."""
    if storage.local is not None or not run.is_run():
        return False
    try:
        if config.resumes(run.read_config()):
            return False
    except ConfigError:
        pass
    print(f"trial: {run.path} held another run (an earlier experiment at {storage.uri}); removed, the trial goes on "
          f"from its own checkpoint", file=sys.stderr)
    shutil.rmtree(run.path)
    return True


def restore_run(checkpoint, run: Path, replay_buffer: bool) -> int | None:
    """Before a trial trains: write its run folder again from its Tune checkpoint when the
    folder lacks it (a trial restarted on another node, or whose local folder was lost), or
    holds only an older one. A folder as far as the checkpoint or further is kept (the same
    state: resume is exact from either). A checkpoint is a training checkpoint's (progress.json:
    {"timesteps": n}) or a pretraining iteration's ({"timesteps": 0, "pretrain_iteration": i},
    before any of training's). Returns the steps the run goes on from (0 within the
    pretraining, None: from the start). checkpoint: tune.get_checkpoint()'s (None: the trial's
    first start); a marker checkpoint (progress.json alone, no run folder) leaves the run folder
    as it is."""
    here = _progress_here(run, replay_buffer)
    if checkpoint is None:
        return _steps(here)
    with contextlib.ExitStack() as stack:
        try:
            folder = stack.enter_context(checkpoint.as_directory())
        except FileNotFoundError:
            folder = None
        if folder is None or not (Path(folder) / "progress.json").is_file():  # Tune's checkpoints all hold it
            where = f"{checkpoint.filesystem.type_name}://{checkpoint.path}"
            raise StorageError(f"out: the trial's checkpoint {where} is missing or empty: the experiment's objects "
                               f"were deleted while it ran; run it again into another folder")
        saved = Path(folder) / RUN_IN_CHECKPOINT
        progress = json.loads((Path(folder) / "progress.json").read_text())
        there = (0, progress["pretrain_iteration"]) if "pretrain_iteration" in progress else (1, progress["timesteps"])
        if not saved.is_dir() or (here is not None and here >= there):
            return _steps(here)
        if run.exists():
            shutil.rmtree(run)
        run.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(saved, run)
    return _steps(there)
