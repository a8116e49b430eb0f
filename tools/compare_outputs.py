#!/usr/bin/env python3
"""compare.py A B: compare two run_all.sh output folders file by file.

One line per file: `same`, `differs: <what>` or `skipped (<reason>)`, then the list of the
parts left out (with the reason for each) and a summary. Exit status 0 when everything
compared is the same (and no file is on one side only), 1 otherwise, 2 for bad usage.

Every file is compared byte for byte unless a rule in RULES below names it; a rule leaves
out only the parts that two runs of the same old code (668449a) do not reproduce (timings,
time stamps, random ids, memory addresses, Ray/Tune's own state) and compares the rest
exactly. The evidence for each rule is in its `why` text (old_a vs old_b, see the report).

Everywhere, the OUTDIR's own absolute path (A or B) is replaced by <OUTDIR> and the code
folder's (from OUTDIR/logs/codedir.txt) by <CODEDIR> before comparing, since the outputs
embed the paths they were given (config.yaml's store, experiment.json, tuner.pkl, ...).
Give both OUTDIRs names of the same length (old_a / new_a) so that binary files that embed
a path with its length (zip, parquet) compare equal as well; pickles are compared opcode by
opcode, so a path's length does not matter there.

Run it with the project's venv python (it reads TensorBoard event files with tensorboard's
protobuf classes): .venv/bin/python tools/compare_outputs.py A B [--quiet]
"""

from __future__ import annotations

import base64
import csv
import fnmatch
import html as htmlmod
import io
import json
import pickletools
import re
import shutil
import sqlite3
import struct
import sys
import tempfile
import zipfile
from pathlib import Path

# ----------------------------------------------------------------------------- key lists
# metrics.json / result.json / trials.csv: farm.alloc.train's timings (UpdateTimer) and the
# experiment trial's own timings.
TRAIN_TIMING = ["wall_seconds", "steps_per_second", "update_seconds", "outside_update_share", "pretrain_seconds"]
TRIAL_TIMING = TRAIN_TIMING + ["train_seconds", "evaluate_seconds"]
# Keys Ray Tune adds to every reported result (its clock, its random trial id, the pid of the
# trial actor). hostname / node_ip / training_iteration / done are the same in both runs: kept.
TUNE_AUTO = ["timestamp", "date", "time_this_iter_s", "time_total_s", "time_since_restore", "pid", "trial_id"]
REPORT_TIMING_HEADERS = {"wall (s)", "steps/s", "update (s)", "share outside updates", "ms per step",
                         *TRIAL_TIMING, "predict_seconds", "seconds_per_step"}
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
MASK = "<masked>"

# ----------------------------------------------------------------------------- rules
# (glob on the path relative to OUTDIR, kind, params, why). First match wins. `pair` rules
# pair files whose names hold a time stamp / pid (compared by their canonical name).
RULES = [
    ("logs/steps.tsv", "skip", {}, "the harness's own wall time per step"),
    ("logs/codedir.txt", "skip", {}, "the harness's note of CODEDIR (used to mask CODEDIR paths)"),
    ("logs/*.err", "stderr", {},
     "stderr: tqdm progress bars redraw with \\r at times, rates and ETAs that are wall-clock; kept: each "
     "bar's description and final n/total, every other line; '... in X s' / 'X s in all' / 'evaluations X s' "
     "wall times masked"),
    ("logs/pe-table.out", "text_subs", {"subs": [(r"(?m)^\(\d+(?:\.\d+)? s\)$", "(<T> s)")]},
     "stdout's last line '(N s)' is the command's wall time (time.perf_counter)"),
    ("logs/table.out", "text_subs", {"subs": [(r"(the rest from the store) \(\d+(?:\.\d+)? s\)", r"\1 (<T> s)")]},
     "stdout's '(N s)' after 'the rest from the store' is fill_table's wall seconds"),
    ("logs/train.out", "text_subs",
     {"subs": [(r'("(?:' + "|".join(TRAIN_TIMING) + r')": )[^,\n]+', r"\1" + MASK)]},
     "stdout prints metrics.json: its timing keys " + ", ".join(TRAIN_TIMING) + " masked"),
    ("logs/suite.out", "suite_out", {},
     "stdout's leaderboard: its last column 'ms/step' is the policies' decision wall time (seconds_per_step); "
     "masked with its padding (the column's width follows the widest time)"),
    ("logs/eval-games.out", "text_subs",
     {"subs": [(r"(Ray task\(s\) \(coarse tasks\)), \d+(?:\.\d+)? games/s", r"\1, <N> games/s")]},
     "stdout's live engagements line: games/s is a wall-clock rate"),
    ("logs/claims.out", "text_subs",
     {"subs": [(r"(?m)^(  measured: minutes to the plateau.*)$", lambda m: NUMBER.sub("<N>", m.group(1)))]},
     "claim (c)'s 'measured' line: minutes of training to the plateau, from the trials' wall-clock times "
     "(numbers masked; the verdict line is compared)"),
    ("report.html", "report", {},
     "report.html embeds timings: the 'generated <date time>' line, the training tables' columns wall (s), "
     "steps/s, update (s), share outside updates, the leaderboard's 'ms per step', the sweep's runs.jsonl "
     "(time, seconds, nodes: Ray node ids) and suite.json (warm_seconds, evaluation_seconds, seconds) in "
     "<pre>, claim (c)'s measured minutes, and the <title>'s OUTDIR folder name; those masked, the rest "
     "(all images, all other cells) compared"),
    ("*.sqlite", "sqlite", {},
     "SQLite store: rows compared through sqlite3 (schema; per key: settings, n_pursuers, n_evaders, key_json, "
     "value_json, checksum) on a copy with its WAL; left out: column `created` (time.time() of the insert) "
     "and the row order (the order parallel Ray tasks finished in)"),
    ("*.sqlite-wal", "skip", {},
     "SQLite write-ahead log: random salts, frame order = insert order; its rows are compared via the .sqlite"),
    ("*.sqlite-shm", "skip", {}, "SQLite WAL index (shared memory): not content; rows compared via the .sqlite"),
    ("*/tb/*/events.out.tfevents.*", "tfevents", {},
     "TensorBoard event file: its name holds the start time, host and pid; each event's wall_time and the "
     "'time/*' scalars (SB3's time/fps) are left out; every other event (step, tag, value) compared"),
    ("experiments/*/tune/experiment_state-*.json", "skip", {},
     "Ray Tune's own experiment state: name and content carry its start time stamp, random trial-id prefix, "
     "Ray session temp paths, trials in scheduling order, driver-loop counters and timing stats"),
    ("experiments/*/tune/basic-variant-state-*.json", "skip", {},
     "Ray Tune's search-algorithm state (a pickle): holds the random trial-id prefix, the time-stamped "
     "session name and the /tmp/ray/session_<time>_<pid> path"),
    ("experiments/*/tune/*/result.json", "jsonl", {"keys": TUNE_AUTO + TRIAL_TIMING},
     "Tune's per-trial result log: Tune's own keys " + ", ".join(TUNE_AUTO) + " (clock, random trial id, "
     "actor pid) and the trial timings " + ", ".join(TRIAL_TIMING) + " masked"),
    ("experiments/*/tune/*/progress.csv", "csv", {"columns": TUNE_AUTO + TRIAL_TIMING},
     "Tune's per-trial progress table: same columns as result.json masked"),
    ("*/pretrain/iteration_*.pkl", "pickle", {"float_keys": ["seconds"], "torch_storage_keys": True},
     "pretraining iteration file (sealed: its checksum header left out, the pickle compared): the float after "
     "the key seconds (the iteration's wall time) masked, and the policy tensors' storage keys"),
    ("*/checkpoints/rl_model_state_*_steps.pkl", "pickle",
     {"float_keys": ["wall_seconds", "update_seconds", "pretrain_seconds"], "torch_storage_keys": True,
      "added_keys": ["pretrain"]},
     "RunState pickle (sealed: its checksum header left out; the key pretrain, which the sealed RunState "
     "adds, dropped when the before side lacks it): the floats after the keys wall_seconds / update_seconds "
     "(UpdateTimer) and pretrain_seconds (the pretraining's wall time) masked, and in "
     "torch_rng's tensor (torch's legacy serialisation, a pickle inside the pickle) the storage key, which is "
     "the storage's C pointer (e.g. 94340541712288 vs 94574139369696); every other opcode and byte compared"),
    ("*.pkl", "pickle", {}, None),
    ("*.zip", "sb3zip", {},
     "SB3 model zip: members compared one by one (policy.pth, pytorch_variables.pth, optimizers, "
     "system_info.txt, version: bytes); left out: the zip headers' member dates (time of saving), and in "
     "`data`: start_time (time.time_ns()), ep_info_buffer's 't' (Monitor's seconds since start; r and l "
     "compared), and the memory addresses ' at 0x...' in SB3's human-readable reprs of classes"),
    ("*/metrics.json", "json", {"keys": TRAIN_TIMING}, "training metrics: its timing keys masked"),
    ("experiments/*/trials/*/result.json", "json", {"keys": TRIAL_TIMING}, "trial result: its timing keys masked"),
    ("experiments/*/trials.csv", "csv", {"columns": TRIAL_TIMING}, "trials table: its timing columns masked"),
    ("suite/episodes.csv", "csv", {"columns": ["predict_seconds"]},
     "suite episodes: predict_seconds (the policy's decision wall time) masked"),
    ("suite/leaderboard.csv", "csv", {"columns": ["seconds_per_step"]},
     "leaderboard: seconds_per_step (decision wall time) masked"),
    ("suite/suite.json", "json", {"keys": ["warm_seconds", "evaluation_seconds", "seconds"]},
     "suite manifest: its info timings masked"),
    ("*runs.jsonl", "jsonl", {"keys": ["time", "seconds"], "values_only": ["nodes"]},
     "sweep run log: time (time stamp) and seconds masked; nodes: Ray's random node ids as keys, only the "
     "shard counts compared"),
    ("experiments/*/claims.csv", "claims_csv", {},
     "claims: the `measured` cell of claim (c) (minutes of training to the plateau, from wall-clock times) "
     "has its numbers masked; verdict and every other cell compared"),
]


def rule_for(rel: str):
    for pattern, kind, params, why in RULES:
        if fnmatch.fnmatchcase(rel, pattern):  # fnmatch's * also matches '/'
            return pattern, kind, params, why
    return None, "bytes", {}, None


# ----------------------------------------------------------------------------- pairing
_CANON = [(re.compile(r"(events\.out\.tfevents)\.\d+\.[^/]+$"), r"\1.*"),
          (re.compile(r"(experiment_state|basic-variant-state)-\d{4}-\d\d-\d\d_\d\d-\d\d-\d\d\.json$"), r"\1-*.json")]


def canonical(rel: str) -> str:
    for rx, rep in _CANON:
        rel = rx.sub(rep, rel)
    return rel


def listing(root: Path) -> dict[str, str]:
    out: dict[str, list[str]] = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            rel = p.relative_to(root).as_posix()
            out.setdefault(canonical(rel), []).append(rel)
    result = {}
    for c, rels in out.items():
        if len(rels) == 1:
            result[c] = rels[0]
        else:  # several files of one canonical name (e.g. two event files): pair in sorted order
            for i, r in enumerate(sorted(rels)):
                result[f"{c}#{i}"] = r
    return result


# ----------------------------------------------------------------------------- side
class Side:
    def __init__(self, root: Path):
        self.root = root.resolve()
        code = self.root / "logs" / "codedir.txt"
        self.code = code.read_text().strip() if code.exists() else None
        self.subs = [(str(self.root).encode(), b"<OUTDIR>")]
        if self.code:
            self.subs.append((self.code.encode(), b"<CODEDIR>"))

    def norm_bytes(self, data: bytes) -> bytes:
        for a, b in self.subs:
            data = data.replace(a, b)
        return data

    def norm_text(self, text: str) -> str:
        for a, b in self.subs:
            text = text.replace(a.decode(), b.decode())
        return text

    def read(self, rel: str) -> bytes:
        return self.norm_bytes((self.root / rel).read_bytes())

    def text(self, rel: str) -> str:
        return self.norm_text((self.root / rel).read_bytes().decode("utf-8"))


# ----------------------------------------------------------------------------- helpers
def first_diff_line(a: str, b: str) -> str:
    la, lb = a.splitlines(), b.splitlines()
    for i, (x, y) in enumerate(zip(la, lb)):
        if x != y:
            return f"line {i + 1}: {x[:120]!r} vs {y[:120]!r}"
    return f"{len(la)} vs {len(lb)} lines"


def json_diff(a, b, path="", out=None, limit=12):
    out = [] if out is None else out
    if len(out) >= limit:
        return out
    if isinstance(a, dict) and isinstance(b, dict):
        if list(a) != list(b) and set(a) == set(b):
            out.append(f"{path or '/'}: key order")
        for k in list(a) + [k for k in b if k not in a]:
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'A' if k in a else 'B'}")
            else:
                json_diff(a[k], b[k], f"{path}/{k}", out, limit)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: {len(a)} vs {len(b)} items")
        for i, (x, y) in enumerate(zip(a, b)):
            json_diff(x, y, f"{path}[{i}]", out, limit)
    elif a != b and not (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
        out.append(f"{path}: {str(a)[:60]!r} vs {str(b)[:60]!r}")
    return out


def mask_json(obj, keys, values_only=()):
    """A copy with the values of `keys` (anywhere) replaced by MASK; `values_only` dicts become their values."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            if k in keys:
                out[k] = MASK
            elif k in values_only and isinstance(v, dict):
                out[k] = sorted(v.values(), key=repr)
            else:
                out[k] = mask_json(v, keys, values_only)
        return out
    if isinstance(obj, list):
        return [mask_json(v, keys, values_only) for v in obj]
    return obj


def dumps(obj) -> str:
    return json.dumps(obj, sort_keys=False, allow_nan=True)


def csv_rows(text: str):
    return list(csv.reader(io.StringIO(text, newline="")))


def mask_csv(rows, columns):
    if not rows:
        return rows, []
    header = rows[0]
    idx = [i for i, c in enumerate(header) if c in columns]
    masked = [header] + [[MASK if i in idx and i < len(r) else x for i, x in enumerate(r)] for r in rows[1:]]
    return masked, [header[i] for i in idx]


def csv_diff(ra, rb) -> str:
    if not ra or not rb:
        return f"{len(ra)} vs {len(rb)} rows"
    if ra[0] != rb[0]:
        only_a, only_b = [c for c in ra[0] if c not in rb[0]], [c for c in rb[0] if c not in ra[0]]
        return (f"header differs: only A {only_a}, only B {only_b}"
                + ("" if set(ra[0]) != set(rb[0]) else " (column order)"))
    header = ra[0]
    parts = []
    if len(ra) != len(rb):
        parts.append(f"{len(ra) - 1} vs {len(rb) - 1} data rows")
    cols, rows = {}, []
    for i, (x, y) in enumerate(zip(ra[1:], rb[1:]), start=1):
        if x != y:
            rows.append(i)
            for j in range(max(len(x), len(y))):
                if (x[j] if j < len(x) else None) != (y[j] if j < len(y) else None):
                    name = header[j] if j < len(header) else f"#{j}"
                    cols.setdefault(name, (i, x[j] if j < len(x) else None, y[j] if j < len(y) else None))
    if rows:
        parts.append(f"{len(rows)} row(s) differ (data rows {rows[:8]}{'...' if len(rows) > 8 else ''}), columns "
                     + ", ".join(f"{c} (row {r}: {str(u)[:30]!r} vs {str(v)[:30]!r})"
                                 for c, (r, u, v) in list(cols.items())[:6]))
    return "; ".join(parts) or "bytes differ (quoting/line endings)"


# ----------------------------------------------------------------------------- comparers
# each returns (same: bool, detail: str, left_out: str|None)

def cmp_bytes(a: Side, b: Side, ra: str, rb: str, params):
    da, db = a.read(ra), b.read(rb)
    if da == db:
        return True, "", None
    if rb.endswith((".csv", ".json", ".jsonl", ".yaml", ".out", ".err", ".txt", ".html")):
        try:
            ta, tb = da.decode(), db.decode()
            if ra.endswith(".csv"):
                return False, csv_diff(csv_rows(ta), csv_rows(tb)), None
            if ra.endswith(".json"):
                try:
                    d = json_diff(json.loads(ta), json.loads(tb))
                    return False, ("keys " + "; ".join(d)) if d else "formatting: " + first_diff_line(ta, tb), None
                except ValueError:
                    pass
            return False, first_diff_line(ta, tb), None
        except UnicodeDecodeError:
            pass
    return False, f"bytes differ ({len(da)} vs {len(db)} bytes)", None


def cmp_masked_text(a, b, ra, rb, mask):
    """The two texts, the same as they are, or the same once mask(text) is applied to both."""
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None
    ta, tb = mask(ta), mask(tb)
    return ta == tb, "" if ta == tb else first_diff_line(ta, tb), "masked"


def cmp_text_subs(a, b, ra, rb, params):
    def mask(t):
        for rx, rep in params["subs"]:
            t = re.sub(rx, rep, t)
        return t
    return cmp_masked_text(a, b, ra, rb, mask)


_TQDM = re.compile(r"^(?P<desc>.*?)(?::\s*)?\s*\d+%\|[^|]*\|\s*(?P<n>\d+)/(?P<total>\d+) \[[^\]]*\]\s*$")
# a bar past its total (tqdm then drops the percentage and the total): "steps: 30208step [00:26, 1146.44step/s]"
_TQDM_PAST = re.compile(r"^(?P<desc>[^:]*):\s*(?P<n>\d+)(?P<unit>[A-Za-z]+) \[[\d:]+, [^\]]*\]\s*$")
_ERR_TIMES = [(re.compile(r"\bin \d+(?:\.\d+)? s\b"), "in <T> s"),
              (re.compile(r"\b\d+(?:\.\d+)? s in all\b"), "<T> s in all"),
              (re.compile(r"\bevaluations \d+(?:\.\d+)? s\b"), "evaluations <T> s")]


def reduce_stderr(text: str) -> str:
    out = []
    for line in text.split("\n"):
        segs = [s for s in line.split("\r") if s.strip()]
        if not segs:
            out.append("")
            continue
        last = segs[-1]
        m, past = _TQDM.match(last), _TQDM_PAST.match(last)
        if m:
            out.append(f"[bar] {m.group('desc').strip()} {m.group('n')}/{m.group('total')}")
        elif past:
            out.append(f"[bar] {past.group('desc').strip()} {past.group('n')}{past.group('unit')}")
        elif any(_TQDM.match(s) for s in segs[:-1]):  # a bar and text after it on one line
            out.append(last)
        else:
            out.append("\r".join(segs))
    text = "\n".join(out)
    for rx, rep in _ERR_TIMES:
        text = rx.sub(rep, text)
    return text


def cmp_stderr(a, b, ra, rb, params):
    return cmp_masked_text(a, b, ra, rb, reduce_stderr)


def cmp_suite_out(a, b, ra, rb, params):
    def mask(t):
        lines, on = [], False
        for line in t.splitlines(keepends=True):
            if "ms/step" in line:  # the header: its width follows the widest value
                on = True
                line = re.sub(r"\s+ms/step(\s*)$", " " + MASK + r"\1", line)
            elif on and line.strip() and not line.startswith("wrote "):
                line = re.sub(r"\s+\S+(\s*)$", " " + MASK + r"\1", line)
            else:
                on = False
            lines.append(line)
        return "".join(lines)
    return cmp_masked_text(a, b, ra, rb, mask)


def cmp_json(a, b, ra, rb, params):
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None
    ja, jb = json.loads(ta), json.loads(tb)
    keys = set(params.get("keys", ()))
    ma, mb = mask_json(ja, keys, params.get("values_only", ())), mask_json(jb, keys, params.get("values_only", ()))
    # formatting too: the masked objects re-serialised must match, and the raw text with the masked
    # values cut out must match (so key order / indentation changes show)
    rx = re.compile(r'("(?:' + "|".join(map(re.escape, keys)) + r')":\s*)(?:"[^"]*"|[^,\n}\]]+)') if keys else None
    ra_txt, rb_txt = (rx.sub(r"\1" + MASK, ta), rx.sub(r"\1" + MASK, tb)) if rx else (ta, tb)
    if ma == mb and ra_txt == rb_txt:
        return True, "", "masked"
    diffs = json_diff(ma, mb)
    what = ("keys " + "; ".join(diffs)) if diffs else ("formatting: " + first_diff_line(ra_txt, rb_txt))
    return False, what, "masked"


def cmp_jsonl(a, b, ra, rb, params):
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None
    la, lb = [l for l in ta.splitlines()], [l for l in tb.splitlines()]
    if len(la) != len(lb):
        return False, f"{len(la)} vs {len(lb)} lines", "masked"
    keys, vo = set(params.get("keys", ())), params.get("values_only", ())
    for i, (x, y) in enumerate(zip(la, lb), start=1):
        if x == y:
            continue
        mx, my = mask_json(json.loads(x), keys, vo), mask_json(json.loads(y), keys, vo)
        if mx != my or list(json.loads(x)) != list(json.loads(y)):
            return False, f"line {i}: keys " + "; ".join(json_diff(mx, my) or ["key order"]), "masked"
    return True, "", "masked"


def cmp_csv(a, b, ra, rb, params):
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None
    (ma, _), (mb, _) = mask_csv(csv_rows(ta), set(params["columns"])), mask_csv(csv_rows(tb), set(params["columns"]))
    if ma == mb:
        return True, "", "masked"
    return False, csv_diff(ma, mb), "masked"


def cmp_claims_csv(a, b, ra, rb, params):
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None

    def mask(rows):
        if not rows:
            return rows
        h = rows[0]
        ci, mi = h.index("claim"), h.index("measured")
        return [h] + [[NUMBER.sub("<N>", x) if j == mi and r[ci].startswith("(c)") else x for j, x in enumerate(r)]
                      for r in rows[1:]]
    ma, mb = mask(csv_rows(ta)), mask(csv_rows(tb))
    return ma == mb, "" if ma == mb else csv_diff(ma, mb), "masked"


def cmp_sqlite(a, b, ra, rb, params):
    def rows(side, rel):
        src = side.root / rel
        with tempfile.TemporaryDirectory() as tmp:  # a copy: opening the store must not checkpoint its WAL
            for suffix in ("", "-wal", "-shm"):
                if Path(str(src) + suffix).exists():
                    shutil.copy2(str(src) + suffix, Path(tmp) / (src.name + suffix))
            con = sqlite3.connect(Path(tmp) / src.name)
            try:
                schema = con.execute("SELECT type, name, tbl_name, sql FROM sqlite_master "
                                     "ORDER BY type, name").fetchall()
                tables = {}
                for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type='table' ORDER BY name"):
                    cols = [r[1] for r in con.execute(f"PRAGMA table_info({t})")]
                    keep = [c for c in cols if c != "created"]
                    order = "key" if "key" in cols else ", ".join(keep)
                    tables[t] = (cols, con.execute(f"SELECT {', '.join(keep)} FROM {t} ORDER BY {order}").fetchall())
            finally:
                con.close()
        return schema, tables
    sa, ta = rows(a, ra)
    sb, tb = rows(b, rb)
    if sa != sb:
        return False, "schema differs", "masked"
    for t in ta:
        ca, xa = ta[t]
        cb, xb = tb.get(t, (None, None))
        if ca != cb:
            return False, f"table {t}: columns {ca} vs {cb}", "masked"
        xa = [tuple(a.norm_text(v) if isinstance(v, str) else v for v in r) for r in xa]
        xb = [tuple(b.norm_text(v) if isinstance(v, str) else v for v in r) for r in xb]
        if xa != xb:
            ka, kb = {r[0]: r for r in xa}, {r[0]: r for r in xb}
            only_a, only_b = set(ka) - set(kb), set(kb) - set(ka)
            keep = [c for c in ca if c != "created"]
            diff_cols = sorted({keep[i] for k in set(ka) & set(kb) for i in range(len(keep)) if ka[k][i] != kb[k][i]})
            return False, (f"table {t}: {len(xa)} vs {len(xb)} rows, {len(only_a)} keys only in A, {len(only_b)} only "
                           f"in B, differing columns {diff_cols}"), "masked"
    return True, f"{sum(len(x) for _, x in ta.values())} rows", "masked"


_TORCH_LEGACY_MAGIC = b"\x80\x02\x8a\nl\xfc\x9cF\xf9 j\xa8P\x19."  # torch.save's legacy format starts so
_TORCH_KEY = re.compile(rb"X(....)(\d+)", re.S)  # protocol-2 BINUNICODE of a digits-only string


def mask_torch_keys(blob: bytes) -> bytes:
    """A torch legacy-format blob with its storage keys (str(id-like C pointer)) masked."""
    def f(m):
        return b"X<storage-key>" if int.from_bytes(m.group(1), "little") == len(m.group(2)) else m.group(0)
    return _TORCH_KEY.sub(f, blob)


def pickle_ops(data: bytes, side: Side, float_keys=(), string_mask=None, torch_keys=False):
    """The opcode stream, strings path-normalised, FRAME sizes and the string opcodes' width
    (SHORT_BINUNICODE / BINUNICODE) dropped, memo indices kept; floats right after one of
    float_keys (a dict key) masked."""
    out, masked = [], 0
    memo, top = {}, None  # the memo's strings; the string last pushed (None: not a string)
    for op, arg, _ in pickletools.genops(data):
        name = op.name
        if name == "FRAME":
            continue
        if isinstance(arg, str) and "UNICODE" in name:
            arg = side.norm_text(arg)
            if string_mask:
                arg = string_mask(arg)
            name = "STR"
        elif isinstance(arg, (bytes, bytearray)):
            arg = side.norm_bytes(bytes(arg))
            if torch_keys and arg.startswith(_TORCH_LEGACY_MAGIC):
                arg = mask_torch_keys(arg)
            name = "BYTES" if "BYTES" in name else name
        if name == "MEMOIZE":
            memo[len(memo)] = top
        elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
            memo[int(arg)] = top
        elif name in ("GET", "BINGET", "LONG_BINGET"):
            top = memo.get(int(arg))
        else:
            if name in ("BINFLOAT", "FLOAT") and top in float_keys:
                arg, masked = MASK, masked + 1
            top = arg if name == "STR" else None
        out.append((name, arg))
    return out, masked


SEALS = (b"swarm-farm checkpoint state\n", b"swarm-farm pretrain iteration\n")  # farm.core.sealed's first lines


def sealed_payload(data: bytes) -> bytes:
    """The pickle of a sealed file (a first line of SEALS, a JSON header line of checksums, then the
    pickle), else data itself: a sealed file and an unsealed one of the same pickle compare equal."""
    if data.startswith(SEALS):
        return data.split(b"\n", 2)[2]
    return data


def without_added_keys(pa: bytes, pb: bytes, keys) -> tuple[bytes, bytes]:
    """Both pickles of a dict loaded and dumped again (protocol 4), the after side's top-level `keys`
    that the before side lacks dropped: a key the new code adds compares as no change."""
    import pickle

    da, db = pickle.loads(pa), pickle.loads(pb)
    if isinstance(da, dict) and isinstance(db, dict):
        db = {k: v for k, v in db.items() if k in da or k not in keys}
    return pickle.dumps(da, protocol=4), pickle.dumps(db, protocol=4)


def cmp_pickle(a, b, ra, rb, params):
    da, db = a.read(ra), b.read(rb)
    if da == db:
        return True, "", None
    fk, tk = tuple(params.get("float_keys", ())), params.get("torch_storage_keys", False)
    pa, pb = sealed_payload((a.root / ra).read_bytes()), sealed_payload((b.root / rb).read_bytes())
    if params.get("added_keys"):
        pa, pb = without_added_keys(pa, pb, params["added_keys"])
    oa, _ = pickle_ops(pa, a, fk, torch_keys=tk)
    ob, _ = pickle_ops(pb, b, fk, torch_keys=tk)
    if oa == ob:
        return True, "", ("masked" if fk else "paths")
    for i, (x, y) in enumerate(zip(oa, ob)):
        if x != y:
            return False, f"opcode {i}: {str(x)[:100]} vs {str(y)[:100]}", "masked" if fk else None
    return False, f"{len(oa)} vs {len(ob)} opcodes", None


_ADDR = re.compile(r" at 0x[0-9a-f]+")


def _sb3_data(text: str, side: Side):
    d = json.loads(text)
    left = []
    if "start_time" in d:
        d["start_time"], _ = MASK, left.append("start_time")
    for k, v in d.items():
        if isinstance(v, dict) and ":serialized:" in v:
            for kk, vv in v.items():
                if kk not in (":serialized:", ":type:") and isinstance(vv, str) and _ADDR.search(vv):
                    v[kk] = _ADDR.sub(" at 0x<addr>", vv)
            if k == "ep_info_buffer":
                ops, n = pickle_ops(base64.b64decode(v[":serialized:"]), side, ("t",))
                v[":serialized:"] = ops
    return d


def cmp_sb3zip(a, b, ra, rb, params):
    da, db = a.read(ra), b.read(rb)
    if da == db:
        return True, "", None
    za, zb = zipfile.ZipFile(a.root / ra), zipfile.ZipFile(b.root / rb)
    na, nb = za.namelist(), zb.namelist()
    if na != nb:
        return False, f"members {na} vs {nb}", None
    bad = []
    for n in na:
        xa, xb = a.norm_bytes(za.read(n)), b.norm_bytes(zb.read(n))
        if xa == xb:
            continue
        if n == "data":
            ja, jb = _sb3_data(xa.decode(), a), _sb3_data(xb.decode(), b)
            if ja == jb and list(ja) == list(jb):
                continue
            bad.append("data: " + "; ".join(json_diff(ja, jb, limit=6)))
        else:
            bad.append(f"{n} ({len(xa)} vs {len(xb)} bytes)")
    ia = [(i.filename, i.compress_type, i.external_attr) for i in za.infolist()]
    ib = [(i.filename, i.compress_type, i.external_attr) for i in zb.infolist()]
    if ia != ib:
        bad.append("member headers (compression/attributes)")
    return not bad, "; ".join(bad), "masked"


def _tf_events(path: Path, side: Side):
    from tensorboard.compat.proto import event_pb2

    data = path.read_bytes()
    pos, out = 0, []
    while pos < len(data):
        (n,) = struct.unpack("<Q", data[pos:pos + 8])
        rec = data[pos + 12:pos + 12 + n]
        pos += 12 + n + 4
        ev = event_pb2.Event()
        ev.ParseFromString(rec)
        ev.wall_time = 0
        if ev.HasField("summary"):
            keep = [v for v in ev.summary.value if not v.tag.startswith("time/")]
            del ev.summary.value[:]
            ev.summary.value.extend(keep)
            if not keep:
                continue
        out.append(side.norm_bytes(ev.SerializeToString(deterministic=True)))
    return out


def cmp_tfevents(a, b, ra, rb, params):
    ea, eb = _tf_events(a.root / ra, a), _tf_events(b.root / rb, b)
    if ea == eb:
        return True, f"{len(ea)} events", "masked"
    for i, (x, y) in enumerate(zip(ea, eb)):
        if x != y:
            return False, f"event {i} differs", "masked"
    return False, f"{len(ea)} vs {len(eb)} events", "masked"


_TABLE = re.compile(r"<table\b.*?</table>", re.S)
_TH = re.compile(r"<th(?:\s[^>]*)?>(.*?)</th>", re.S)
_TR = re.compile(r"<tr(?:\s[^>]*)?>(.*?)</tr>", re.S)
_TD = re.compile(r"(<td(?:\s[^>]*)?>)(.*?)(</td>)", re.S)
_PRE = re.compile(r"(<pre>)(.*?)(</pre>)", re.S)


def mask_report(text: str) -> str:
    text = re.sub(r"generated \d{4}-\d\d-\d\d \d\d:\d\d:\d\d", "generated <TIME>", text)

    def table(m):
        t = m.group(0)
        head, sep, body = t.partition("</thead>")
        if not sep:
            head, body = "", t
        headers = [htmlmod.unescape(h).strip() for h in _TH.findall(head)]
        cols = {i for i, h in enumerate(headers) if h in REPORT_TIMING_HEADERS}

        def row(rm):
            cells = iter(range(10 ** 6))

            def cell(cm):
                i = next(cells)
                inner = cm.group(2)
                if i in cols:
                    inner = MASK
                elif htmlmod.unescape(inner).startswith("minutes to the plateau"):
                    inner = NUMBER.sub("<N>", inner)
                return cm.group(1) + inner + cm.group(3)
            return rm.group(0)[: rm.start(1) - rm.start(0)] + _TD.sub(cell, rm.group(1)) + "</tr>"
        return head + sep + _TR.sub(row, body)

    text = _TABLE.sub(table, text)

    def pre(m):
        raw = htmlmod.unescape(m.group(2))
        keys = {"time", "seconds", "warm_seconds", "evaluation_seconds"}
        try:
            doc = json.loads(raw)
            return m.group(1) + htmlmod.escape(json.dumps(mask_json(doc, keys, ("nodes",)), indent=2)) + m.group(3)
        except ValueError:
            pass
        try:
            lines = [json.loads(line) for line in raw.splitlines() if line.strip()]
            masked = "\n".join(json.dumps(mask_json(d, keys, ("nodes",))) for d in lines)
            return m.group(1) + htmlmod.escape(masked) + m.group(3)
        except ValueError:
            return m.group(0)
    return _PRE.sub(pre, text)


def cmp_report(a, b, ra, rb, params):
    ta, tb = a.text(ra), b.text(rb)
    if ta == tb:
        return True, "", None
    # <title> names the OUTDIR folder (root.name), not its path
    masked_title = "<title>swarm-farm report: <OUTDIR-name></title>"
    ta = ta.replace(f"<title>swarm-farm report: {htmlmod.escape(a.root.name)}</title>", masked_title)
    tb = tb.replace(f"<title>swarm-farm report: {htmlmod.escape(b.root.name)}</title>", masked_title)
    ma, mb = mask_report(ta), mask_report(tb)
    if ma == mb:
        return True, "", "masked"
    sa, sb = re.split(r"(<[^>]+>)", ma), re.split(r"(<[^>]+>)", mb)
    for i, (x, y) in enumerate(zip(sa, sb)):
        if x != y:
            return False, f"token {i}: {x[:80]!r} vs {y[:80]!r}", "masked"
    return False, f"{len(sa)} vs {len(sb)} tokens", "masked"


COMPARERS = {"bytes": cmp_bytes, "text_subs": cmp_text_subs, "stderr": cmp_stderr, "suite_out": cmp_suite_out,
             "json": cmp_json, "jsonl": cmp_jsonl, "csv": cmp_csv, "claims_csv": cmp_claims_csv,
             "sqlite": cmp_sqlite, "pickle": cmp_pickle, "sb3zip": cmp_sb3zip, "tfevents": cmp_tfevents,
             "report": cmp_report}


def main(argv):
    quiet = "--quiet" in argv
    args = [x for x in argv if x != "--quiet"]
    if len(args) != 2:
        print(__doc__.split("\n\n")[0], file=sys.stderr)
        return 2
    a, b = Side(Path(args[0])), Side(Path(args[1]))
    for s in (a, b):
        if not s.root.is_dir():
            print(f"compare: {s.root}: not a folder", file=sys.stderr)
            return 2
    if len(str(a.root)) != len(str(b.root)):
        print(f"note: the OUTDIR paths differ in length ({len(str(a.root))} vs {len(str(b.root))}); a binary file "
              f"that embeds its path with a length may then differ", file=sys.stderr)
    la, lb = listing(a.root), listing(b.root)
    ok, counts, used = True, {"same": 0, "differs": 0, "skipped": 0, "only": 0}, {}
    for c in sorted(set(la) | set(lb)):
        ra, rb = la.get(c), lb.get(c)
        shown = c
        if ra is None or rb is None:
            print(f"only in {'A' if ra else 'B'}  {ra or rb}")
            counts["only"] += 1
            ok = False
            continue
        pattern, kind, params, why = rule_for(rb)
        if kind == "skip":
            counts["skipped"] += 1
            used.setdefault(pattern, why)
            print(f"skipped ({why})  {shown}")
            continue
        try:
            same, detail, left = COMPARERS[kind](a, b, ra, rb, params)
        except Exception as e:  # a file that does not parse as its rule expects
            same, detail, left = False, f"could not compare as {kind}: {type(e).__name__}: {e}", None
        if left == "masked" and why:
            used.setdefault(pattern, why)
        tag = "same" if same else "differs"
        counts[tag] += 1
        ok &= same
        extra = f"  [{kind}: {pattern}]" if left == "masked" else ""
        if not same:
            print(f"differs  {shown}: {detail}{extra}")
        elif not quiet:
            print(f"same  {shown}{extra}")
    print("\nLeft out (rule: why):")
    for pattern, why in used.items():
        print(f"  {pattern}: {why}")
    print("  (everywhere) the OUTDIR's absolute path -> <OUTDIR>, CODEDIR's -> <CODEDIR>: outputs embed the paths "
          "they were given")
    print(f"\n{counts['same']} same, {counts['differs']} differ, {counts['skipped']} skipped, {counts['only']} on one "
          f"side only -> {'OK' if ok else 'DIFFERENT'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
