"""Parametric Monte Carlo sweeps on Ray: shards of games as coarse tasks,
backpressure with ray.wait, atomic Parquet per shard, resumable, deterministic.

Layout of a sweep's folder:
    sweep.json                       the resolved config and its id (a hash)
    shards/p00003-s00012.parquet     one file per shard: per-game statistics
    summary.parquet, summary.csv     one row per point

Game g of a point is game g of its case with the sweep's seed, default_rng([seed, g])
(docs/model.md section 6), as in run_case and the capture-time service: the numbers do
not depend on the number of workers, on shard boundaries, on interruptions, or on where
the point stands in the config.

A worker or node that dies mid-shard is Ray's to handle: the shard task is retried
(up to MAX_RETRIES times; Ray's `ray_tasks{IsRetry!="0"}` metric shows the retries).
A shard's own exception fails the sweep at once: it would fail the same way again.
"""

from __future__ import annotations

import io
import json
import os
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from workers import ENGINE_VERSION, SEEDING, Case, CaptureStats, results_statistics, run_games

from farm import metrics
from farm.errors import ConfigError, SweepError
from farm.output import atomic_write_bytes, write_table
from farm.sweep.config import Point, SweepConfig

MAX_RETRIES = 3


@dataclass(frozen=True)
class Shard:
    point: int
    number: int
    start: int
    stop: int

    @property
    def file_name(self) -> str:
        return f"p{self.point:05d}-s{self.number:05d}.parquet"

    @property
    def games(self) -> int:
        return self.stop - self.start


def simulate_shard(case: Case, seed: int, shard: Shard) -> tuple[pd.DataFrame, int]:
    """Play one shard's games; returns its per-game rows and the game-steps simulated."""
    res = run_games(case, seed, shard.start, shard.stop)
    df = results_statistics(res, case.tau, first_game=shard.start)
    df.insert(0, "shard", np.int64(shard.number))
    df.insert(0, "point", np.int64(shard.point))
    df["steps"] = res.steps
    df["capture_times"] = list(res.capture_times)
    df["escape_times"] = list(res.escape_times)
    return df, int(res.steps.sum())


def _remote_shard(case: Case, seed: int, shard: Shard, sweep_name: str):
    """Body of the Ray task: simulate, record worker-side metrics; returns the rows
    and the id of the node that ran it."""
    import ray

    t0 = time.perf_counter()
    df, steps = simulate_shard(case, seed, shard)
    metrics.record_shard(sweep_name, shard.games, steps, time.perf_counter() - t0)
    return df, ray.get_runtime_context().get_node_id()


def table_bytes(df: pd.DataFrame) -> bytes:
    buf = io.BytesIO()
    pq.write_table(pa.Table.from_pandas(df, preserve_index=False), buf)
    return buf.getvalue()


class SweepRun:
    """A sweep bound to an output folder."""

    def __init__(self, config: SweepConfig, out: str | Path):
        self.config = config
        self.out = Path(out)
        self.points: list[Point] = config.points()
        self.sweep_id = config.sweep_id()
        self.shard_dir = self.out / "shards"

    # ----- the folder -------------------------------------------------------------
    def prepare(self) -> None:
        """Create or reopen the folder; refuse one that holds another sweep."""
        manifest = self.out / "sweep.json"
        if self.out.exists() and not self.out.is_dir():
            raise ConfigError(f"--out: {self.out} exists and is not a folder")
        if manifest.exists():
            try:
                other = json.loads(manifest.read_text()).get("sweep_id")
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                raise ConfigError(f"--out: {manifest} is unreadable; choose another folder") from None
            if other != self.sweep_id:
                raise ConfigError(
                    f"--out: {self.out} holds sweep {other}, not this config's {self.sweep_id}; choose another folder"
                )
        elif self.out.exists() and any(self.out.iterdir()):
            raise ConfigError(f"--out: {self.out} is not empty and holds no sweep; choose another folder")
        self.shard_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.shard_dir.glob(".*.tmp"):
            stale.unlink(missing_ok=True)
        doc = {
            "sweep_id": self.sweep_id,
            "engine_version": ENGINE_VERSION,
            "seeding": SEEDING,
            "config": self.config.model_dump(mode="json"),
            "points": [
                {"index": p.index, "changes": p.changes, "case": p.case.to_dict(), "case_key": p.case.key(),
                 "games": p.games, "shard_games": p.shard_games}
                for p in self.points
            ],
        }
        if not manifest.exists():
            atomic_write_bytes(manifest, json.dumps(doc, indent=2).encode())

    def all_shards(self) -> list[Shard]:
        return [Shard(p.index, k, a, b) for p in self.points for k, a, b in p.shards()]

    def missing_shards(self) -> list[Shard]:
        return [s for s in self.all_shards() if not (self.shard_dir / s.file_name).exists()]

    def store(self, shard: Shard, df: pd.DataFrame) -> None:
        atomic_write_bytes(self.shard_dir / shard.file_name, table_bytes(df))

    # ----- running ----------------------------------------------------------------
    def run_in_process(self, shards: list[Shard], progress=None) -> None:
        for shard in shards:
            df, _ = simulate_shard(self.points[shard.point].case, self.config.seed, shard)
            self.store(shard, df)
            if progress:
                progress(shard.games)

    def run_on_ray(self, shards: list[Shard], workers: int, progress=None) -> dict:
        """Run shards as Ray tasks, at most `workers` at once; returns counts."""
        import ray
        from ray.exceptions import RayError, RayTaskError

        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(_remote_shard)
        name = self.config.name
        recorder = metrics.DriverMetrics(name)
        pending = deque(shards)
        in_flight: dict = {}
        counts = {"done": 0, "nodes": {}}
        recorder.pending(len(pending))
        while pending or in_flight:
            while pending and len(in_flight) < workers:
                shard = pending.popleft()
                in_flight[task.remote(self.points[shard.point].case, self.config.seed, shard, name)] = shard
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                shard = in_flight.pop(ref)
                try:
                    df, node = ray.get(ref)
                except RayTaskError as e:  # the shard's own error: the same again on a retry
                    cause = e.cause if e.cause is not None else e
                    raise SweepError(f"shard {shard.file_name} failed: {type(cause).__name__}: "
                                     f"{str(cause).splitlines()[0] if str(cause) else ''}") from None
                except RayError as e:  # its worker or node died more often than Ray retries
                    raise SweepError(f"shard {shard.file_name} failed {MAX_RETRIES + 1} times; "
                                     f"last: {type(e).__name__}; rerun to resume") from None
                self.store(shard, df)
                counts["nodes"][node] = counts["nodes"].get(node, 0) + 1
                counts["done"] += 1
                recorder.done()
                if progress:
                    progress(shard.games)
            recorder.pending(len(pending) + len(in_flight))
        return counts

    def log_run(self, info: dict) -> None:
        """Append one line per run to runs.jsonl: when, where and what happened."""
        line = {"time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **info}
        with open(self.out / "runs.jsonl", "a") as f:
            f.write(json.dumps(line) + "\n")

    # ----- results ----------------------------------------------------------------
    def read_games(self) -> pd.DataFrame:
        frames = []
        for shard in self.all_shards():
            path = self.shard_dir / shard.file_name
            try:
                frames.append(pq.read_table(path).to_pandas())
            except (OSError, pa.ArrowInvalid) as e:
                raise SweepError(f"{path}: unreadable shard ({type(e).__name__}); delete it and rerun") from None
        df = pd.concat(frames, ignore_index=True)
        return df.sort_values(["point", "game"], kind="stable").reset_index(drop=True)

    def summarize(self) -> pd.DataFrame:
        games = self.read_games()
        rows = []
        for point in self.points:
            per = games[games["point"] == point.index]
            case = point.case.to_dict()
            row = {"point": point.index}
            row.update({k: (json.dumps(v) if isinstance(v, (list, dict)) or v is None else v) for k, v in case.items()})
            row["case_key"] = point.case.key()
            row.update(CaptureStats.from_games(per).flat())
            rows.append(row)
        summary = pd.DataFrame(rows)
        write_table(summary, self.out / "summary", "parquet")
        write_table(summary, self.out / "summary", "csv")
        return summary


def run_sweep(config: SweepConfig, out, *, address=None, workers: int | None = None, use_ray: bool = True,
              show_progress: bool = True, metrics_port: int | None = None) -> tuple[pd.DataFrame, dict]:
    """Run (or resume) a sweep into `out`; returns (summary, info)."""
    from farm.progress import GameProgress

    run = SweepRun(config, out)
    run.prepare()
    todo = run.missing_shards()
    total_games = sum(s.games for s in run.all_shards())
    done_games = total_games - sum(s.games for s in todo)
    info = {"sweep_id": run.sweep_id, "shards": len(run.all_shards()), "skipped": len(run.all_shards()) - len(todo),
            "done": 0, "workers": 0, "seconds": 0.0, "nodes": {}}
    t0 = time.perf_counter()
    if todo:
        from contextlib import nullcontext

        from farm.runtime import ray_cluster

        cluster = ray_cluster(address, num_cpus=workers, metrics_port=metrics_port) if use_ray else nullcontext()
        with cluster as ray:  # connected (or refused in one line) before the progress bar shows
            bar = GameProgress(total_games, done_games, enabled=show_progress)
            try:
                if use_ray:
                    cpus = int(ray.cluster_resources().get("CPU", 1))
                    joined = address or os.environ.get("RAY_ADDRESS")
                    n = max(1, min(workers or cpus, cpus) if not joined else (workers or cpus))
                    info["workers"] = n
                    info.update(run.run_on_ray(todo, n, progress=bar.update))
                else:
                    info["workers"] = 1
                    run.run_in_process(todo, progress=bar.update)
                    info["done"] = len(todo)
            finally:
                bar.close()
    info["seconds"] = time.perf_counter() - t0
    summary = run.summarize()
    if todo:
        run.log_run(info)
    return summary, info


def summary_view(summary: pd.DataFrame, changed: list[str]) -> pd.DataFrame:
    """The columns of a sweep's summary worth showing: the point, what varies, the time to
    capture everybody and the fractions captured (and escaped, for games with an exit)."""
    cols = ["point", *changed, "n_games", "last_capture_mean", "last_capture_ci95_low", "last_capture_ci95_high",
            "last_capture_n_censored", "frac_captured_tau_mean", "p_all_captured_tau"]
    if "frac_escaped_mean" in summary and summary["frac_escaped_mean"].gt(0).any():  # games with an exit
        cols += ["frac_escaped_tau_mean", "mean_escape_mean"]
    return summary[[c for c in cols if c in summary.columns]].copy()


def format_summary(summary: pd.DataFrame, changed: list[str]) -> str:
    return summary_view(summary, changed).to_string(index=False, float_format=lambda x: f"{x:.3f}")


def print_info(info: dict, file=sys.stderr) -> None:
    print(
        f"sweep {info['sweep_id']}: {info['shards']} shards, {info['skipped']} already stored, "
        f"{info['done']} run on {info['workers']} worker(s) in {info['seconds']:.1f} s",
        file=file,
    )

