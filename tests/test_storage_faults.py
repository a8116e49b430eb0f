"""Object storage that cannot work or fails mid-run (farm/studies/experiments/storage.py), on a
real S3-compatible server (moto's, conftest.s3_bucket), real closed ports and real files: an
unsupported or unreachable URI, one without a bucket or without credentials, is refused in one
line before Ray within seconds; a file:// folder whose parents do not exist gets them; objects
deleted while an experiment runs are a StorageError naming the experiment and what is missing."""

import json
import time
from pathlib import Path

import pytest
import yaml
from conftest import S3_ENV, farm_main, free_port, s3_bucket
from helpers import farm_refusal

from farm.studies.experiments.storage import ExperimentStorage

REPO = Path(__file__).resolve().parents[1]
SECONDS = 10  # an object-store URI that cannot work is refused within this


def refused_experiment(tmp_path: Path, out: str) -> str:
    """`farm experiments` of the smoke config into out: its one-line error (exit status 2) within
    SECONDS (before Ray: conftest's RAY_ADDRESS is a closed port), no store made."""
    raw = yaml.safe_load((REPO / "configs/experiments/smoke.yaml").read_text())
    store = tmp_path / "store.sqlite"
    raw.update(base=str(REPO / raw["base"]), store=str(store))
    path = tmp_path / "smoke.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    t0 = time.perf_counter()
    status, _, err = farm_main("experiments", path, "--out", out, "--quiet")
    took = time.perf_counter() - t0
    line = farm_refusal(status, err)
    assert took < SECONDS, (took, line)
    assert not store.exists()
    return line


SUPPORTED = "(a local folder, or s3://, gs://, gcs://, abfs://, abfss://, hdfs://, viewfs://, file://)"


@pytest.mark.parametrize("out", ["mock:///x", "nosuch://bucket/x"])
def test_an_unsupported_scheme_is_refused_in_one_line_within_seconds(tmp_path, out):
    """mock:// is a URI pyarrow opens, but its filesystem does not pickle: Ray's workers could
    not be handed it."""
    scheme = out.split(":")[0]
    assert refused_experiment(tmp_path, out) == (f"farm: error: --out: {out}: {scheme}:// is not a storage an "
                                                 f"experiment can live in {SUPPORTED}")


def test_an_unreachable_object_store_is_refused_in_one_line_within_seconds(tmp_path, monkeypatch):
    for name, value in S3_ENV.items():
        monkeypatch.setenv(name, value)
    port = free_port()  # closed
    out = f"s3://farm/x?endpoint_override=127.0.0.1:{port}&scheme=http"
    line = refused_experiment(tmp_path, out)
    assert line.startswith(f"farm: error: --out: {out}: reaching it: no answer within 5 s (")
    assert "Request ID" not in line


def test_gcs_without_credentials_is_refused_within_seconds(tmp_path, monkeypatch):
    """No credentials anywhere (the metadata server a closed port): GCS's client retries for
    minutes by default."""
    closed = f"127.0.0.1:{free_port()}"
    monkeypatch.delenv("GOOGLE_APPLICATION_CREDENTIALS", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.config/gcloud
    monkeypatch.setenv("CLOUDSDK_CONFIG", str(tmp_path / "gcloud"))
    monkeypatch.setenv("GCE_METADATA_ROOT", closed)
    monkeypatch.setenv("GCE_METADATA_HOST", closed)
    line = refused_experiment(tmp_path, "gs://farm-results/x")
    assert line.startswith("farm: error: --out: gs://farm-results/x: reaching it: credentials refused or missing (")
    assert line.endswith("; set GOOGLE_APPLICATION_CREDENTIALS, or gcloud auth application-default login")


@pytest.fixture(scope="module")
def s3():
    with s3_bucket("farm") as client:
        yield client


@pytest.mark.parametrize("out", ["s3://", "s3://?scheme=http"])
def test_s3_without_a_bucket_is_refused_not_read_as_every_bucket(s3, tmp_path, out):
    assert refused_experiment(tmp_path, out) == (f"farm: error: --out: {out} names no bucket (it would be the root "
                                                 f"of every bucket); give s3://BUCKET/FOLDER")


def test_a_bucket_that_does_not_exist_is_refused_before_ray(s3, tmp_path):
    assert refused_experiment(tmp_path, "s3://nobucket/x") == (
        "farm: error: --out: s3://nobucket/x: bucket 'nobucket' does not exist; make it first, or name another")


def test_a_file_uri_whose_folders_do_not_exist_gets_them(tmp_path):
    """A local filesystem by URI needs its folders (S3 does not): a trial's upload, the driver's
    download and its tables go into folders made for them."""
    root = tmp_path / "not" / "yet" / "exp"
    storage = ExperimentStorage(root.as_uri())
    run = tmp_path / "scratch" / "run"
    (run / "best").mkdir(parents=True)
    (run / "model.zip").write_text("model")
    (run / "best" / "best_model.zip").write_text("best")
    storage.finish("p0_s0", {"trial": "p0_s0"}, run)
    assert (root / "trials" / "p0_s0" / "run" / "best" / "best_model.zip").read_text() == "best"
    assert json.loads((root / "trials" / "p0_s0" / "result.json").read_text()) == {"trial": "p0_s0"}
    storage.write_manifest({"name": "smoke", "digest": "abc", "trials": [], "fields": []})
    with storage.staged() as stage:
        storage.stage_results(stage, ["p0_s0"])
        assert (stage / "trials" / "p0_s0" / "run" / "model.zip").read_text() == "model"
        (stage / "trials.csv").write_text("a\n")
        storage.publish(stage, ["trials.csv"])
    assert (root / "trials.csv").read_text() == "a\n"
    fresh = tmp_path / "other" / "exp"
    ExperimentStorage(fresh.as_uri()).check()  # before Ray: the folder is made
    assert fresh.is_dir()


def test_objects_deleted_mid_run_name_the_experiment_and_what_is_missing(s3, tmp_path):
    """The bucket emptied while the experiment ran: the driver reading back the manifest, a trial
    its result, a restarted trial its Tune checkpoint; each one line naming the experiment's
    folder and the object, without S3's request id."""
    from pyarrow import fs
    from ray import tune

    from farm.core.errors import StorageError

    storage = ExperimentStorage("s3://farm/lost")
    storage.write_manifest({"name": "smoke", "digest": "abc", "trials": [], "fields": []})
    storage.write_result("p0_s0", {"trial": "p0_s0"})
    assert storage.finished("p0_s0")
    for key in ("lost/experiment.json", "lost/trials/p0_s0/result.json"):
        s3.delete_object(Bucket="farm", Key=key)

    with pytest.raises(StorageError) as e, storage.staged():
        pass
    assert str(e.value) == ("out: s3://farm/lost: experiment.json is missing: the experiment's objects were deleted "
                            "while it ran; run it again")
    with pytest.raises(StorageError) as e:
        storage.read_result("p0_s0")
    message = str(e.value)
    assert message.startswith("out: s3://farm/lost: reading trials/p0_s0/result.json: not found (")
    assert message.endswith("were its objects deleted while the experiment ran?")
    assert "\n" not in message and "Request ID" not in message

    from farm.studies.experiments.storage import restore_run

    checkpoint = tune.Checkpoint("farm/lost/tune/p0_s0/checkpoint_000001", filesystem=fs.FileSystem.from_uri(
        "s3://farm/lost")[0])
    with pytest.raises(StorageError) as e:
        restore_run(checkpoint, tmp_path / "run", replay_buffer=True)
    assert str(e.value) == ("out: the trial's checkpoint s3://farm/lost/tune/p0_s0/checkpoint_000001 is missing or "
                            "empty: the experiment's objects were deleted while it ran; run it again into another "
                            "folder")


def test_an_exploit_s_learned_storage_is_checked_before_any_game(tmp_path, monkeypatch):
    """farm exploit's learned best responses run as an experiment after the fixed adversaries and
    the exact search: a storage of theirs that cannot work is refused before any of it (before
    Ray: conftest's RAY_ADDRESS is a closed port), naming learned.storage."""
    from farm.core.errors import ConfigError
    from farm.studies.exploit.config import ExploitConfig
    from farm.studies.exploit.run import run_exploit

    for name, value in S3_ENV.items():
        monkeypatch.setenv(name, value)
    closed = f"s3://farm/x?endpoint_override=127.0.0.1:{free_port()}&scheme=http"
    for storage, words in [("mock:///x", "learned.storage: mock:///x: mock:// is not a storage an experiment can "
                                         "live in"),
                           (closed, f"learned.storage: {closed}: reaching it: no answer within 5 s (")]:
        config = ExploitConfig(name="small", scenarios=["outnumbered_3x3"], allocators=["spread_evenly"],
                               heuristics=["fewest_ahead"], episodes=3, learned={"storage": storage},
                               store=str(tmp_path / "store.sqlite"), env={"games": 8})
        t0 = time.perf_counter()
        with pytest.raises(ConfigError) as e:
            run_exploit(config, tmp_path / "out", show_progress=False)
        assert time.perf_counter() - t0 < SECONDS
        assert str(e.value).startswith(words) and "\n" not in str(e.value)
        assert not (tmp_path / "out").exists() and not (tmp_path / "store.sqlite").exists()
