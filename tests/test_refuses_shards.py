"""Issue 28: a sweep's shard file that is not its shard whole is never read as a result. A
valid shard copied over another's name, a shard of another sweep dropped into shards/, a few
flipped bytes, a truncated file: each is reported in one line, moved to shards/damaged/ (kept),
played again on the rerun, and the summary equals an undamaged run's. Shards are played in
process (`--no-ray`): what is checked is the folder, not Ray."""

import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml

from farm.core.errors import SweepError
from farm.games.sweep import SweepRun, load_sweep_config, run_sweep

ROOT = Path(__file__).resolve().parents[1]
# configs/smoke.yaml made small: 2 points x 6 games, 3 games a shard
SMALL = {**yaml.safe_load((ROOT / "configs/smoke.yaml").read_text()), "games_per_point": 6, "shard_games": 3}


def config_file(tmp: Path, **changes) -> Path:
    raw = {**SMALL, **changes}
    raw["vary"] = {"grid": {"n_pursuers": [1, 3]}}
    path = tmp / f"sweep{len(list(tmp.glob('sweep*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def swept(path: Path, out: Path):
    return run_sweep(load_sweep_config(path), out, use_ray=False, show_progress=False)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """An undamaged run: (tmp, config path, folder, summary)."""
    tmp = tmp_path_factory.mktemp("shards")
    path = config_file(tmp)
    out = tmp / "clean"
    summary, _ = swept(path, out)
    return tmp, path, out, summary


def flip_a_value(path: Path, column: str = "mean_capture", row: int = 1) -> None:
    """Flip four bytes of one stored value (a float64 of column at row) in the file."""
    import struct

    value = pd.read_parquet(path)[column][row]
    data = bytearray(path.read_bytes())
    at = data.find(struct.pack("<d", value))
    assert at > 0
    for k in range(2, 6):
        data[at + k] ^= 0xFF
    path.write_bytes(bytes(data))


def numbers(summary: pd.DataFrame) -> pd.DataFrame:
    return summary.drop(columns=[c for c in summary.columns if "seconds" in c])


def other_sweeps_shard(tmp: Path) -> Path:
    """Shard p00000-s00000 of another sweep (another seed): the same name, games and columns."""
    out = tmp / "other"
    if not out.exists():
        swept(config_file(tmp, seed=7), out)
    return out / "shards" / "p00000-s00000.parquet"


DAMAGES = {
    "copied over another's name": (lambda shards, tmp: shutil.copy(shards / "p00000-s00000.parquet",
                                                                   shards / "p00000-s00001.parquet"),
                                   "p00000-s00001", "holds other rows"),
    "of another sweep": (lambda shards, tmp: shutil.copy(other_sweeps_shard(tmp), shards / "p00000-s00000.parquet"),
                         "p00000-s00000", "belongs to sweep"),
    "four flipped bytes in a value": (lambda shards, tmp: flip_a_value(shards / "p00001-s00000.parquet"),
                                      "p00001-s00000", ""),
    "truncated": (lambda shards, tmp: (shards / "p00001-s00001.parquet").write_bytes(
        (shards / "p00001-s00001.parquet").read_bytes()[:300]), "p00001-s00001", "unreadable"),
}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_a_damaged_shard_is_never_a_result_and_is_played_again(clean, tmp_path, capsys, damage):
    tmp, path, out, summary = clean
    folder = tmp_path / "run"
    shutil.copytree(out, folder)
    do, name, problem = DAMAGES[damage]
    do(folder / "shards", tmp)

    with pytest.raises(SweepError) as e:  # read as it is, the folder is refused, never summed
        SweepRun(load_sweep_config(path), folder).read_games()
    assert "\n" not in str(e.value) and f"{name}.parquet" in str(e.value) and problem in str(e.value)

    capsys.readouterr()
    again, info = swept(path, folder)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "damaged" in ln]
    assert len(lines) == 1 and f"shards/{name}.parquet" in lines[0] and problem in lines[0], lines
    assert info["damaged"] == 1 and info["done"] == 1 and info["skipped"] == 3
    pd.testing.assert_frame_equal(numbers(again), numbers(summary))
    kept = list((folder / "shards" / "damaged").iterdir())
    assert [p.name.split(".parquet")[0] for p in kept] == [name]  # nothing thrown away


def test_an_undamaged_rerun_plays_nothing_and_reports_nothing(clean, tmp_path, capsys):
    tmp, path, out, summary = clean
    folder = tmp_path / "run"
    shutil.copytree(out, folder)
    capsys.readouterr()
    again, info = swept(path, folder)
    assert info["damaged"] == 0 and info["skipped"] == 4 and "damaged" not in capsys.readouterr().err
    pd.testing.assert_frame_equal(numbers(again), numbers(summary))


def test_the_checksum_is_of_the_rows_whatever_their_chunks(clean):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from farm.games.shards import ROWS_SHA256_KEY, rows_sha256

    _, _, out, _ = clean
    table = pq.read_table(out / "shards" / "p00000-s00000.parquet")
    expected = table.schema.metadata[ROWS_SHA256_KEY.encode()].decode()
    assert rows_sha256(table) == expected
    rechunked = pa.concat_tables([table.slice(0, 1), table.slice(1)])
    assert rechunked.column(0).num_chunks == 2 and rows_sha256(rechunked) == expected
    df = table.to_pandas()
    df.loc[1, "mean_capture"] += 1e-12
    assert rows_sha256(pa.Table.from_pandas(df, preserve_index=False)) != expected
