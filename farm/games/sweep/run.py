"""Parametric Monte Carlo sweeps on Ray: shards of games as coarse tasks,
backpressure with ray.wait, atomic Parquet per shard, resumable, deterministic.

Layout of a sweep's folder:
    sweep.json                       the resolved config and its id (a hash)
    shards/p00003-s00012.parquet     one file per shard: per-game statistics
    summary.parquet, summary.csv     one row per point

Game g of a point is game g of its case with the sweep's seed, default_rng([seed, g])
(docs/model.md section 6), as in run_case and the capture-time service: the numbers depend
on neither the workers, the shard boundaries, interruptions nor the point's place in the config.

A worker or node that dies mid-shard is Ray's to handle: the shard task (farm.games.tasks) is
retried, and Ray's `ray_tasks{IsRetry!="0"}` metric shows the retries. A shard's own
exception fails the sweep at once: it would fail the same way again.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from farm.core.errors import ConfigError, SweepError
from farm.core.output import atomic_write_bytes, check_writable_folder, write_table
from farm.games.shards import SWEEP_ID_KEY, play_shard, shard_problem, warn_coarse_steps, write_shard
from farm.games.sweep.config import FULL_CHECK_POINTS, Point, SweepConfig
from farm.runtime import metrics
from workers import ENGINE_VERSION, SEEDING, CaptureStats, Case, game_statistics


@dataclass(frozen=True)
class Shard:
    """One shard of a sweep: games start..stop-1 of point `point`, its `number`-th."""

    point: int
    number: int
    start: int
    stop: int

    @property
    def file_name(self) -> str:
        """Its Parquet file's name in the sweep's shards/ folder."""
        return f"p{self.point:05d}-s{self.number:05d}.parquet"

    @property
    def games(self) -> int:
        """How many games it plays."""
        return self.stop - self.start


def simulate_shard(case: Case, seed, shard: Shard) -> pd.DataFrame:
    """One shard's rows as its file keeps them: point, shard, then farm.games.shards.play_shard's
    per-game columns with detail (steps, capture and escape times)."""
    return _label(play_shard(case, seed, shard.start, shard.stop, detail=True), shard)


def _label(df: pd.DataFrame, shard: Shard) -> pd.DataFrame:
    df.insert(0, "shard", np.int64(shard.number))
    df.insert(0, "point", np.int64(shard.point))
    return df


class SweepRun:
    """A sweep bound to an output folder."""

    def __init__(self, config: SweepConfig, out: str | Path):
        self.config = config
        self.out = Path(out)
        self.points: list[Point] = config.points()
        self.sweep_id = config.sweep_id(self.points)  # the points planned once: planning a large grid is slow
        self.shard_dir = self.out / "shards"
        self.damaged: list[str] = []  # one line per shard file found damaged and played again (missing_shards)

    # ----- the folder -------------------------------------------------------------
    def prepare(self, rebuild: bool = False) -> None:
        """Create or reopen the folder; refuse one that holds another sweep. rebuild: write a
        damaged or missing sweep.json again from this config, when every shard in the folder
        carries this config's sweep id."""
        manifest = self.out / "sweep.json"
        if self.out.exists() and not self.out.is_dir():
            raise ConfigError(f"out: {self.out} exists and is not a folder", field="out")
        how = "rebuild (`farm sweep CONFIG --out DIR --rebuild`) writes it again from CONFIG if the shards are CONFIG's"
        rewrite = False
        if manifest.exists():
            try:
                other = json.loads(manifest.read_text()).get("sweep_id")
            except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
                if not rebuild:
                    raise ConfigError(f"out: {manifest} is damaged; {how}", field="out") from None
                self._check_shards_are_mine()
                rewrite = True
            else:
                if other != self.sweep_id:
                    raise ConfigError(f"out: {self.out} holds sweep {other}, not this config's {self.sweep_id}; "
                                      "choose another folder", field="out")
        elif self.out.exists() and any(self.out.iterdir()):
            if not rebuild:
                raise ConfigError(f"out: {self.out} is not empty and holds no sweep.json; {how}, else choose "
                                  "another folder", field="out")
            self._check_shards_are_mine()
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
        if rewrite or not manifest.exists():
            atomic_write_bytes(manifest, json.dumps(doc, indent=2).encode())

    def _check_shards_are_mine(self) -> None:
        """ConfigError unless the folder has shards and every one carries this sweep's id."""
        files = sorted(self.shard_dir.glob("*.parquet")) if self.shard_dir.is_dir() else []
        if not files:
            raise ConfigError(f"out: {self.out} has no shards to rebuild sweep.json from; choose another folder",
                              field="out")
        for path in files:
            try:
                meta = pq.read_schema(path).metadata or {}
            except (OSError, pa.ArrowInvalid) as e:
                raise ConfigError(f"out: {path} is unreadable ({type(e).__name__}); delete it and rerun",
                                  field="out") from None
            found = meta.get(SWEEP_ID_KEY.encode(), b"").decode()
            if not found:
                raise ConfigError(f"out: {path} carries no sweep id (written before swarm-farm 0.3): sweep.json "
                                  "cannot be rebuilt safely; choose another folder", field="out")
            if found != self.sweep_id:
                raise ConfigError(f"out: {path} belongs to sweep {found}, not this config's {self.sweep_id}; "
                                  "choose another folder", field="out")

    def all_shards(self) -> list[Shard]:
        """Every shard of every point, in order."""
        return [Shard(p.index, k, a, b) for p in self.points for k, a, b in p.shards()]

    def missing_shards(self) -> list[Shard]:
        """The shards whose file is not written yet, or is not that shard whole (what a resumed
        run plays): a file that is unreadable, of another sweep, failing its checksum or holding
        other games (farm.games.shards.shard_problem) is moved to shards/damaged/ (kept, never
        read) and its line added to self.damaged."""
        todo = []
        for shard in self.all_shards():
            path = self.shard_dir / shard.file_name
            if not path.exists():
                todo.append(shard)
                continue
            _, problem = self._read(shard)
            if problem is not None:
                aside = self.shard_dir / "damaged" / f"{shard.file_name}.{time.strftime('%Y%m%dT%H%M%S')}"
                aside.parent.mkdir(exist_ok=True)
                path.replace(aside)
                self.damaged.append(f"shards/{shard.file_name}: {problem}; moved to shards/damaged/, played again")
                todo.append(shard)
        return todo

    def _read(self, shard: Shard):
        """(the shard's rows, None) or (None, what is wrong with its file): shard_problem."""
        return shard_problem(self.shard_dir / shard.file_name, self.sweep_id, shard.point, shard.number,
                             shard.start, shard.stop)

    def store(self, shard: Shard, df: pd.DataFrame) -> None:
        """Write a shard's rows to its file, atomically."""
        write_shard(df, self.shard_dir / shard.file_name, self.sweep_id)

    # ----- running ----------------------------------------------------------------
    def run_in_process(self, shards: list[Shard], progress=None) -> None:
        """Play shards one after another in this process; progress(games) after each."""
        for shard in shards:
            self.store(shard, simulate_shard(self.points[shard.point].case, self.config.seed, shard))
            if progress:
                progress(shard.games)

    def run_on_ray(self, shards: list[Shard], workers: int, progress=None) -> dict:
        """Run shards as Ray tasks, at most `workers` at once; returns counts."""
        import ray
        from ray.exceptions import RayError, RayTaskError

        from farm.games.tasks import MAX_RETRIES, _remote_shard
        from farm.runtime import bounded

        name = self.config.name
        recorder = metrics.DriverMetrics(name)
        counts = {"done": 0, "nodes": {}}
        left = len(shards)
        recorder.pending(left)

        def submit(shard: Shard):
            case = self.points[shard.point].case
            return _remote_shard.remote(case, self.config.seed, shard.start, shard.stop, True, name)

        for shard, ref in bounded(submit, shards, workers):
            try:
                df, node = ray.get(ref)
            except RayTaskError as e:  # the shard's own error: the same again on a retry
                cause = e.cause if e.cause is not None else e
                raise SweepError(f"shard {shard.file_name} failed: {type(cause).__name__}: "
                                 f"{str(cause).splitlines()[0] if str(cause) else ''}") from None
            except RayError as e:  # its worker or node died more often than Ray retries
                raise SweepError(f"shard {shard.file_name} failed {MAX_RETRIES + 1} times; "
                                 f"last: {type(e).__name__}; rerun to resume") from None
            self.store(shard, _label(df, shard))
            counts["nodes"][node] = counts["nodes"].get(node, 0) + 1
            counts["done"] += 1
            recorder.done()
            left -= 1
            recorder.pending(left)
            if progress:
                progress(shard.games)
        return counts

    def log_run(self, info: dict) -> None:
        """Append one line per run to runs.jsonl: when, where and what happened."""
        line = {"time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **info}
        with open(self.out / "runs.jsonl", "a") as f:
            f.write(json.dumps(line) + "\n")

    # ----- results ----------------------------------------------------------------
    def read_games(self) -> pd.DataFrame:
        """Every shard's rows, sorted by point and game; SweepError naming a shard file that is
        missing or not its shard whole (shard_problem): never read as a result."""
        frames = []
        for shard in self.all_shards():
            path = self.shard_dir / shard.file_name
            if not path.exists():
                raise SweepError(f"{path}: missing shard; run the sweep again to play it")
            df, problem = self._read(shard)
            if problem is not None:
                raise SweepError(f"{path}: {problem}; run the sweep again to play it again")
            frames.append(df)
        df = pd.concat(frames, ignore_index=True)
        return df.sort_values(["point", "game"], kind="stable").reset_index(drop=True)

    def summarize(self) -> pd.DataFrame:
        """One row per point (its case and CaptureStats.flat()), written to summary.parquet and summary.csv."""
        games = self.read_games()
        rows = []
        for point in self.points:
            per = games[games["point"] == point.index]
            case = point.case.to_dict()
            row = {"point": point.index}
            row.update({k: (json.dumps(v) if isinstance(v, (list, dict)) or v is None else v) for k, v in case.items()})
            row["case_key"] = point.case.key()
            if "capture_score_tau" not in per.columns:  # an older shard, without the score: from its times
                per = per.assign(capture_score_tau=game_statistics(
                    np.stack(per["capture_times"].to_numpy()), point.case.tau)["capture_score_tau"].to_numpy())
            row.update(CaptureStats.from_games(per).flat())
            rows.append(row)
        summary = pd.DataFrame(rows)
        write_table(summary, self.out / "summary", "parquet")
        write_table(summary, self.out / "summary", "csv")
        return summary


def run_sweep(config: SweepConfig, out, *, address=None, workers: int | None = None, use_ray: bool = True,
              show_progress: bool = True, metrics_port: int | None = None, yes: bool = False,
              rebuild: bool = False) -> tuple[pd.DataFrame, dict]:
    """Run (or resume) a sweep into `out`; returns (summary, info).

    A large sweep says its size first and one over farm.games.sizes' limits is refused unless yes;
    rebuild: see SweepRun.prepare."""
    from farm.core.progress import GameProgress
    from farm.games.sizes import check_size
    from farm.runtime import check_workers

    check_workers(workers)
    check_writable_folder(out, "out")  # before planning and playing: a read-only out is found now
    check_size(config.size(), yes=yes, cpus=workers or 2)
    if show_progress and config.count() > FULL_CHECK_POINTS:  # planning them takes a while: say so first
        print(f"sweep: planning {config.count():,} points (each point's case and the sweep's id) ...", file=sys.stderr)
    run = SweepRun(config, out)
    warn_coarse_steps(p.case for p in run.points)
    run.prepare(rebuild)
    todo = run.missing_shards()
    for line in run.damaged:
        print(f"sweep {run.sweep_id}: {line}", file=sys.stderr)
    total_games = sum(s.games for s in run.all_shards())
    done_games = total_games - sum(s.games for s in todo)
    info = {"sweep_id": run.sweep_id, "shards": len(run.all_shards()), "skipped": len(run.all_shards()) - len(todo),
            "damaged": len(run.damaged),
            "done": 0, "workers": 0, "seconds": 0.0, "nodes": {}}
    t0 = time.perf_counter()
    if todo:
        from contextlib import nullcontext

        from farm.runtime import ray_cluster, starts_local_ray, tasks_in_flight

        starts_ray = use_ray and starts_local_ray(address)  # only then is `workers` its CPU count
        cluster = (ray_cluster(address, num_cpus=workers if starts_ray else None, metrics_port=metrics_port) if use_ray
                   else nullcontext())
        with cluster as ray:  # connected (or refused in one line) before the progress bar shows
            bar = GameProgress(total_games, done_games, enabled=show_progress)
            try:
                if use_ray:
                    cpus = int(ray.cluster_resources().get("CPU", 1))
                    n = tasks_in_flight(workers, cpus, address)
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
    """summary_view as a text table."""
    return summary_view(summary, changed).to_string(index=False, float_format=lambda x: f"{x:.3f}")


def print_info(info: dict, file=sys.stderr) -> None:
    """One line on what a run did: shards, already stored, run, workers, seconds."""
    print(
        f"sweep {info['sweep_id']}: {info['shards']} shards, {info['skipped']} already stored, "
        f"{info['done']} run on {info['workers']} worker(s) in {info['seconds']:.1f} s",
        file=file,
    )

