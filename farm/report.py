"""`farm report RESULTS_DIR`: one self-contained HTML page of everything a run produced.

Images and data are inline (data: URIs, inline CSS and script), so the page
opens anywhere without network access. Sections with no data say which command
would produce them. The page is built whole in memory and written atomically:
bad input never leaves a partial file.
"""

from __future__ import annotations

import base64
import html
import json
import sqlite3
import time
from pathlib import Path

import pandas as pd

from farm.core.errors import NotAStoreError, ReportError, StoreCorruptError, SwarmFarmError
from workers import ENGINE_VERSION

__all__ = ["ReportError", "build_report", "write_report"]


def _read_table(path: Path) -> pd.DataFrame:
    """A results table (.parquet, else CSV); ReportError when the file is damaged or unreadable.

    What such a file raises: OSError (missing, a folder, unreadable, a Parquet file whose
    metadata do not parse), ValueError (pandas' ParserError and EmptyDataError,
    UnicodeDecodeError, pyarrow's ArrowInvalid for a file that is not Parquet or is cut
    short) and pyarrow's other ArrowException (e.g. an encoding it does not implement).
    """
    import pyarrow

    try:
        return pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError, pyarrow.ArrowException) as e:
        raise ReportError(f"{path}: unreadable results file ({type(e).__name__})") from None


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ReportError(f"{path}: unreadable results file ({type(e).__name__})") from None


def _png(path: Path) -> bytes:
    data = path.read_bytes()
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise ReportError(f"{path}: not a PNG image")
    return data


def _img(data: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(data).decode()}">'


def _fig_bytes(fig) -> bytes:
    from farm.core.plots import figure_png

    return figure_png(fig, dpi=90)


def _heatmap(grid: pd.DataFrame, title: str, alt: str) -> str:
    """An n_pursuers x n_evaders heatmap as an <img>."""
    from farm.core.plots import draw_heatmap, new_figure

    fig, axes = new_figure(figsize=(5.5, 4))
    draw_heatmap(fig, axes[0, 0], grid, title)
    fig.tight_layout()
    return _img(_fig_bytes(fig), alt)


def _grid(parts) -> str:
    """Figures side by side, wrapping."""
    return "<div class=grid>" + "".join(parts) + "</div>"


def _table(df: pd.DataFrame) -> str:
    inner = df.to_html(index=False, border=0, classes="t", float_format=lambda x: f"{x:.3f}", na_rep="-")
    return f"<div class=scroll>{inner}</div>"


def _axes(figsize):
    """(Figure, Axes) of a one-panel chart."""
    from farm.core.plots import new_figure

    fig, axes = new_figure(figsize=figsize)
    return fig, axes[0, 0]


# ----- sections -------------------------------------------------------------------


def _pe_section(root: Path) -> str | None:
    files = sorted(root.rglob("pe_tables.csv")) + sorted(root.rglob("pe_tables.parquet"))
    if not files:
        return None
    parts = []
    for path in files:
        df = _read_table(path)
        need = {"table", "n_pursuers", "mean", "std", "ci95_low", "ci95_high", "min", "max", "paper_mean"}
        if not need <= set(df.columns):
            raise ReportError(f"{path}: not a PE table (missing {', '.join(sorted(need - set(df.columns)))})")
        cols = ["table", "n_pursuers", "pursuer_policy", "evader_policy", "pursuer_speed", "evader_speed", "games",
                "mean", "std", "ci95_low", "ci95_high", "min", "max", "paper_mean"]  # speeds: tables since engine 2
        view = df[[c for c in cols if c in df.columns]].rename(columns={"paper_mean": "paper"})
        fig, ax = _axes((8, 3.4))
        labels = [f"{t.split(':')[0]}\n{n}p" for t, n in zip(df["table"], df["n_pursuers"])]
        x = range(len(df))
        ax.bar([i - 0.2 for i in x], df["mean"], 0.4, yerr=[df["mean"] - df["ci95_low"], df["ci95_high"] - df["mean"]],
               label="this model (95% CI)", color="tab:blue")
        ax.bar([i + 0.2 for i in x], df["paper_mean"], 0.4, label="paper", color="tab:gray")
        ax.set_xticks(list(x), labels, fontsize=8)
        ax.set_ylabel("mean capture time (s)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        figs = "".join(_img(_png(p), p.name) for p in sorted(path.parent.glob("fig_*.png")))
        parts.append(
            f"<p class=src>{html.escape(str(path))}</p>{_table(view)}{_img(_fig_bytes(fig), 'PE table chart')}"
            f"<h3>Trajectories with Voronoi cells (game 0 of each case)</h3><div class=grid>{figs}</div>"
        )
    return "".join(parts)


def _game_figures(root: Path, used: set[Path]) -> str | None:
    pngs = [p for p in sorted(root.rglob("*.png")) if p not in used and "tables" not in p.parts
            and not p.name.startswith(("fig_", "density_", "training_curve"))]
    if not pngs:
        return None
    used.update(pngs)
    return _grid(f"<figure>{_img(_png(p), p.name)}<figcaption>{html.escape(str(p.relative_to(root)))}</figcaption>"
                 "</figure>" for p in pngs)


def _sweep_section(root: Path) -> str | None:
    manifests = sorted(root.rglob("sweep.json"))
    if not manifests:
        return None
    parts = []
    for manifest in manifests:
        folder = manifest.parent
        doc = _read_json(manifest)
        if not isinstance(doc, dict) or "config" not in doc:
            raise ReportError(f"{manifest}: not a sweep manifest")
        summary_path = folder / "summary.parquet"
        if not summary_path.exists():
            parts.append(f"<h3>{html.escape(doc['config'].get('name', folder.name))}</h3>"
                         "<p>No summary yet: rerun <code>farm sweep</code> on this folder to finish it.</p>")
            continue
        summary = _read_table(summary_path)
        from farm.games.sweep import summary_view, varied_names

        changed = varied_names(doc["config"].get("vary") or {})
        view = summary_view(summary, changed)
        chart = _sweep_chart(summary, changed)
        runs = (folder / "runs.jsonl")
        run_lines = runs.read_text().splitlines() if runs.exists() else []
        parts.append(
            f"<h3>{html.escape(doc['config'].get('name', folder.name))} "
            f"<small>sweep {html.escape(doc.get('sweep_id', '?'))}, "
            f"engine {html.escape(str(doc.get('engine_version', '?')))}</small></h3>"
            f"<p class=src>{html.escape(str(folder))}</p>{chart}{_table(view)}"
            f"<details><summary>configuration</summary>"
            f"<pre>{html.escape(json.dumps(doc['config'], indent=2))}</pre></details>"
            f"<details><summary>runs ({len(run_lines)})</summary>"
            f"<pre>{html.escape(chr(10).join(run_lines))}</pre></details>"
        )
    return "".join(parts)


def _sweep_chart(summary: pd.DataFrame, changed: list[str]) -> str:
    y = "last_capture_mean"
    if {"n_pursuers", "n_evaders"} <= set(changed):
        others = [c for c in changed if c not in ("n_pursuers", "n_evaders")]
        groups = list(summary.groupby(others)) if others else [((), summary)]
        out = []
        for name, g in groups:
            grid = g.pivot_table(index="n_pursuers", columns="n_evaders", values=y)
            out.append(_heatmap(grid, f"mean time to capture all (s) {name if others else ''}", "sweep heatmap"))
        return "<div class=grid>" + "".join(out) + "</div>"
    numeric = [c for c in changed if pd.api.types.is_numeric_dtype(summary[c])]
    if not numeric:
        return ""
    x = numeric[0]
    others = [c for c in changed if c != x]
    fig, ax = _axes((6, 3.5))
    for name, g in (summary.groupby(others) if others else [("", summary)]):
        g = g.sort_values(x)
        ax.errorbar(g[x], g[y], yerr=[g[y] - g["last_capture_ci95_low"], g["last_capture_ci95_high"] - g[y]],
                    marker="o", capsize=3, label=", ".join(map(str, name)) if isinstance(name, tuple) else str(name))
    ax.set_xlabel(x)
    ax.set_ylabel("mean time to capture all (s)")
    if others:
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _img(_fig_bytes(fig), "sweep chart")


def _service_section(root: Path) -> str | None:
    return "".join(filter(None, map(_store_html, sorted(root.rglob("*.sqlite"))))) or None


def _store_html(path: Path) -> str | None:
    """One capture-time store's heatmaps and cases; None for another SQLite file or an empty store."""
    from farm.service.store import StatsStore

    try:
        store = StatsStore(path, read_only=True)
        rows = store.table()
        store.close()
    except NotAStoreError:
        return None
    except (StoreCorruptError, sqlite3.Error) as e:
        raise ReportError(str(e).splitlines()[0]) from None
    if not rows:
        return None
    records = []
    for r in rows:
        case = r["key"]["case"]
        v = r["value"]
        settings = {k: v for k, v in case.items() if k not in ("n_pursuers", "n_evaders")}
        settings.update(games=r["key"]["games"], seed=r["key"]["seed"])
        records.append({"settings": json.dumps(settings, sort_keys=True),
                        "pursuer_policy": case["pursuer_policy"], "evader_policy": case["evader_policy"],
                        "n_pursuers": case["n_pursuers"], "n_evaders": case["n_evaders"],
                        "games": r["key"]["games"], "tau": case["tau"],
                        "mean_capture": v.mean_capture.mean,
                        "frac_within_tau": v.frac_captured_tau,
                        "p_all_within_tau": v.p_all_captured_tau,
                        "engine": case["engine_version"]})
    df = pd.DataFrame(records).sort_values(["pursuer_policy", "evader_policy", "n_pursuers", "n_evaders"])
    figs = []
    for (pp, ep, _), g in df.groupby(["pursuer_policy", "evader_policy", "settings"]):
        grid = g.pivot(index="n_pursuers", columns="n_evaders", values="mean_capture")
        title = (f"{pp} vs {ep}, {g['games'].iloc[0]} games, tau {g['tau'].iloc[0]:g}, "
                 f"engine {g['engine'].iloc[0]}: mean capture time (s)")
        figs.append(_heatmap(grid, title, f"{pp} vs {ep} heatmap"))
    return (f"<p class=src>{html.escape(str(path))}: {len(df)} cases</p><div class=grid>{''.join(figs)}</div>"
            f"<details><summary>all cases</summary>{_table(df.drop(columns='settings'))}</details>")


def _training_section(root: Path) -> str | None:
    return "".join(map(_curve_html, sorted(root.rglob("evaluations.npz")))) or None


def _curve_html(path: Path) -> str:
    """One run's training curve (path: its evaluations.npz), with its metrics.json's numbers when present."""
    from farm.alloc.game.plots import training_curve_figure
    from farm.alloc.training.runs import RunFolder
    from farm.core.errors import ResultsError

    run = RunFolder(path.parent)
    try:
        steps, results = run.evaluations()
        m = run.read_metrics()
    except ResultsError as e:
        raise ReportError(str(e)) from None
    curve = _img(_fig_bytes(training_curve_figure(steps, results)), 'training curve')
    out = f"<p class=src>{html.escape(str(path))}</p>{curve}"
    diverged = run.diverged()
    if diverged is not None:
        out += f"<p><b>Not a result:</b> {html.escape(diverged)}</p>"
    if m is not None:
        m = m.model_dump()
        shown = {"timesteps": "steps", "wall_seconds": "wall (s)", "steps_per_second": "steps/s",
                 "update_seconds": "update (s)", "outside_update_share": "share outside updates",
                 "final_eval_mean_return": "final eval return", "best_eval_mean_return": "best eval return"}
        out += _table(pd.DataFrame([{label: m.get(k) for k, label in shown.items()}]))
    return out


def _eval_section(root: Path) -> str | None:
    tables = sorted(root.rglob("eval_table.csv")) + sorted(root.rglob("eval_table_games.csv"))
    if not tables:
        return None
    label = {"eval_table.csv": "", "eval_table_games.csv": " (--fidelity games: every engaged cell's game simulated)"}
    out = [f"<p class=src>{html.escape(str(p))}{html.escape(label[p.name])}</p>{_table(_read_table(p))}"
           for p in sorted(tables)]
    steps = sorted(root.rglob("behaviour_steps.png"))
    if steps:
        out.append("<p>Behaviour step by step (the trained policy beside the best baseline): coverage is the "
                   "share of the intruder mass that shares a cell with defenders.</p>")
        out.extend(f"<p class=src>{html.escape(str(p))}</p>{_img(_png(p), 'behaviour per step')}" for p in steps)
    return "".join(out)


def _density_section(root: Path) -> str | None:
    pngs = sorted(root.rglob("density_*.png"))
    if not pngs:
        return None
    return _grid(_img(_png(p), p.name) for p in pngs)


def _animations_section(root: Path) -> str | None:
    """Every .gif and .mp4 under root, inlined (a gif as an image, an mp4 as a video), each
    captioned with its path; one over MAX_ANIMATION_BYTES is named, not inlined."""
    files = sorted(p for p in root.rglob("*") if p.suffix.lower() in (".gif", ".mp4") and p.is_file()
                   and not p.name.startswith("."))
    if not files:
        return None
    parts = []
    for p in files:
        caption = f"<figcaption>{html.escape(str(p.relative_to(root)))}</figcaption>"
        data = p.read_bytes()
        if len(data) > MAX_ANIMATION_BYTES:
            parts.append(f"<figure><p class=missing>{len(data) >> 20} MiB: too large to inline</p>{caption}</figure>")
        elif p.suffix.lower() == ".gif":
            src = f"data:image/gif;base64,{base64.b64encode(data).decode()}"
            parts.append(f'<figure><img alt="{html.escape(p.name)}" src="{src}">{caption}</figure>')
        else:
            src = f"data:video/mp4;base64,{base64.b64encode(data).decode()}"
            parts.append(f'<figure><video controls loop muted src="{src}" style="max-width:560px"></video>'
                         f'{caption}</figure>')
    return _grid(parts)


def _leaderboard_section(root: Path) -> str | None:
    """Every suite's leaderboard under root (farm suite: leaderboard.csv), its chart and config."""
    boards = sorted(root.rglob("leaderboard.csv"))
    if not boards:
        return None
    parts = []
    for path in boards:
        board = _read_table(path)
        need = {"scenario", "policy", "episodes", "eliminated_mean", "eliminated_ci95", "return_mean", "return_ci95",
                "breached_mean", "breached_ci95", "coverage_mean", "coverage_ci95", "seconds_per_step"}
        if not need <= set(board.columns):
            raise ReportError(f"{path}: not a leaderboard (missing {', '.join(sorted(need - set(board.columns)))})")

        from farm.studies.suite import leaderboard_view

        view = leaderboard_view(board, coverage=True, ms_label="ms per step")
        chart = path.with_name("leaderboard.png")
        manifest = path.with_name("suite.json")
        doc = _read_json(manifest) if manifest.exists() else None
        title = doc.get("name", path.parent.name) if isinstance(doc, dict) else path.parent.name
        parts.append(
            f"<h3>{html.escape(str(title))}</h3><p class=src>{html.escape(str(path))}</p>"
            + (_img(_png(chart), "leaderboard chart") if chart.exists() else "")
            + "<p>Mean over the episodes ± the half-width of the 95% t interval; every policy of a scenario "
              "played the same seeded episodes. ms per step: the policy's own decision time.</p>"
            + _table(view)
            + (f"<details><summary>configuration</summary><pre>{html.escape(json.dumps(doc, indent=2))}</pre>"
               "</details>" if doc is not None else "")
        )
    return "".join(parts)


def _experiments_section(root: Path) -> str | None:
    """Every experiment under root (farm experiments: experiment.json): its summary over seeds,
    its claims over seeds (claims.csv) and its learning curves over seeds."""
    manifests = sorted(root.rglob("experiment.json"))
    if not manifests:
        return None
    return "".join(_experiment_html(m.parent) for m in manifests)


LEARNING_CURVES_CAPTION = (
    "Learning curves over seeds, one panel per point: the periodic evaluation's return (the mean over its "
    "episodes) against environment steps, finished trials only. The line is the mean over seeds; the band is "
    "the 95% t interval over seeds for 3 seeds or more, the min-max for 2 seeds, none for 1 (each panel's "
    "title says which).")


def _experiment_html(folder: Path) -> str:
    """One experiment folder's part of the Experiments section."""
    from farm.core.errors import ResultsError
    from farm.studies.experiments import summary_table, summary_view
    from farm.studies.experiment_folder import finished_trials, read_manifest
    from farm.studies.experiments.results import learning_curves_figure, point_curves

    try:
        manifest = read_manifest(folder)
        finished = finished_trials(folder, manifest)
        curves = point_curves(folder, manifest)
    except ResultsError as e:
        raise ReportError(str(e)) from None
    out = (f"<h3>{html.escape(str(manifest.get('name', folder.name)))}</h3><p class=src>{html.escape(str(folder))}</p>"
           f"<p>{len(finished)} of {len(manifest['trials'])} trials finished.</p>")
    if not finished:
        return out + "<p class=missing>No finished trial yet: <code>farm experiments</code> on this folder goes on.</p>"
    summary = summary_table(manifest["fields"], pd.DataFrame([t["result"] for t in finished]))
    out += ("<p>Per point: td3's return and intruder mass eliminated on the evaluation episodes, the mean over "
            "seeds ± the half-width of the 95% t interval over seeds, beside the baseline or planner eliminating "
            "the most (the same episodes for every seed).</p>" + _table(summary_view(summary)))
    claims = folder / "claims.csv"
    if claims.exists():
        out += (f"<h4>The paper's claims over seeds</h4><p class=src>{html.escape(str(claims))}</p>"
                f"<div class=prose>{_table(_read_table(claims))}</div>")
    if curves:
        out += (f"<figure>{_img(_fig_bytes(learning_curves_figure(curves)), 'learning curves over seeds')}"
                f"<figcaption>{html.escape(LEARNING_CURVES_CAPTION)}</figcaption></figure>")
    return out


SECTIONS = [
    ("pe", "The paper's pursuit-evasion tables", "farm pe-table --out RESULTS_DIR/pe-table"),
    ("sweeps", "Sweeps", "farm sweep configs/smoke.yaml --out RESULTS_DIR/sweep-smoke"),
    ("service", "Capture-time service table",
     "farm table configs/table_small.yaml --store RESULTS_DIR/capture_times.sqlite"),
    ("training", "Training curves", "farm train CONFIG (the allocation trainer)"),
    ("density", "Density maps of an evaluation episode", "farm eval RUN_DIR"),
    ("eval", "Evaluation against the baselines", "farm eval RUN_DIR"),
    ("leaderboard", "Leaderboard", "farm suite configs/suite_demo.yaml --out RESULTS_DIR/suite"),
    ("experiments", "Experiments",
     "farm experiments configs/experiments/smoke.yaml --out RESULTS_DIR/experiments/smoke"),
    ("games", "Game figures", "farm game --plot RESULTS_DIR/game.png"),
    ("animations", "Animations", "farm game --animate RESULTS_DIR/game.gif, or farm eval RUN_DIR --animate"),
]
# Sections shown only when their data is there (no placeholder): the adapting intruders' studies.
OPTIONAL_SECTIONS = [
    ("exploit", "Exploitability: allocators against adapting intruders"),
    ("robust", "Robust allocators: policy-space response oracles"),
]

MAX_ANIMATION_BYTES = 8 << 20  # a larger animation is linked, not inlined, so that the page stays light

# In CSS and SELF_CHECK, a line ending in a backslash goes on without a line break.
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1200px;color:#222;\
padding:0 1em}
h1{margin-bottom:.2em} h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
small{color:#777;font-weight:normal} .src{color:#777;font-size:.85em;font-family:monospace}
table.t{border-collapse:collapse;font-size:.85em;margin:.6em 0} \
table.t td,table.t th{padding:.25em .6em;border-bottom:1px solid #eee;text-align:right}
table.t th{background:#f5f5f5} img{max-width:100%;margin:.3em 0} .grid{display:flex;flex-wrap:wrap;gap:1em}
.grid img{max-width:560px} .missing{color:#999;font-style:italic} \
pre{background:#f7f7f7;padding:.6em;overflow:auto;font-size:.8em}
#selfcheck{font-size:.8em;color:#777} .scroll{overflow-x:auto} \
.prose table.t td,.prose table.t th{text-align:left;vertical-align:top}
"""

SELF_CHECK = """
<script>
window.__errors = [];
window.addEventListener('error', function (e) { \
window.__errors.push(String(e.message || (e.target && e.target.src) || e)); }, true);
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var s = document.getElementById('selfcheck');
  s.setAttribute('data-images', imgs.length); s.setAttribute('data-loaded', ok);
  s.setAttribute('data-errors', window.__errors.length);
  s.textContent = ok + '/' + imgs.length + ' images loaded, ' + window.__errors.length + ' errors';
});
</script>
"""


def _exploit_section(root: Path) -> str | None:
    """Every exploit under root (farm exploit: exploit.json and table.csv): its table of eliminated
    mass under each adversary, the worst case and the drop."""
    manifests = sorted(root.rglob("exploit.json"))
    parts = []
    for manifest in manifests:
        table_path = manifest.with_name("table.csv")
        if not table_path.exists():
            continue
        doc = _read_json(manifest)
        table = _read_table(table_path)
        from farm.studies.exploit import table_view

        shown = table_view(table)
        parts.append(f"<h3>{html.escape(str(doc.get('name', manifest.parent.name)))}</h3>"
                     f"<p class=src>{html.escape(str(table_path))}</p>"
                     "<p>Eliminated mass (mean over the seeded episodes ± the 95% t interval's half-width) against "
                     "the intruders' drift law, each heuristic, their exact best response (follower; where the "
                     "search fits) and a learned best response (the mean over its seeds); the worst case over "
                     "every adversary but drift, and the drop from drift.</p>" + _table(shown))
    return "".join(parts) or None


def _robust_section(root: Path) -> str | None:
    """Every robust run under root (farm robust: robust.json, nash_conv.csv, payoffs.csv): NashConv
    by iteration and the final cross-play table."""
    parts = []
    for state in sorted(root.rglob("robust.json")):
        folder = state.parent
        if not (folder / "nash_conv.csv").exists():
            continue
        name = _read_json(state).get("name", folder.name)
        curve = folder / "nash_conv.png"
        payoffs = _read_table(folder / "payoffs.csv").rename(columns={"Unnamed: 0": "allocator"})
        parts.append(f"<h3>{html.escape(str(name))}</h3><p class=src>{html.escape(str(folder))}</p>"
                     + (_img(_png(curve), "NashConv by iteration") if curve.exists() else "")
                     + _table(_read_table(folder / "nash_conv.csv"))
                     + "<p>The final cross-play table: each allocator's mean payoff against each intruder "
                       "policy of the final populations.</p>" + _table(payoffs.round(3)))
    return "".join(parts) or None


def build_report(results_dir: str | Path) -> str:
    """The report's HTML page for a results folder, as a string; raises ReportError on bad input.

    Finds under results_dir (at any depth) the PE tables (pe_tables.csv or .parquet),
    sweep folders (sweep.json), capture-time stores (*.sqlite), training runs
    (evaluations.npz), density maps, evaluation tables, suite leaderboards
    (leaderboard.csv, with leaderboard.png and suite.json), experiments (experiment.json:
    their summary, claims and learning curves over seeds), game figures and animations (.gif, .mp4), and makes one
    section of each kind; a kind without data says which command would produce it.
    Raises ReportError when the folder does not exist, holds none of these, or holds a
    damaged one.
    """
    root = Path(results_dir)
    if not root.exists():
        raise ReportError(f"{root}: no such folder")
    if not root.is_dir():
        raise ReportError(f"{root}: not a folder")
    used: set[Path] = set()
    found = {
        "pe": _pe_section(root),
        "sweeps": _sweep_section(root),
        "service": _service_section(root),
        "training": _training_section(root),
        "density": _density_section(root),
        "eval": _eval_section(root),
        "leaderboard": _leaderboard_section(root),
        "experiments": _experiments_section(root),
        "exploit": _exploit_section(root),
        "robust": _robust_section(root),
    }
    used.update(root.rglob("fig_*.png"))
    used.update(root.rglob("leaderboard.png"))
    used.update(root.rglob("learning_curves.png"))
    used.update(root.rglob("nash_conv.png"))
    found["games"] = _game_figures(root, used)
    found["animations"] = _animations_section(root)
    if not any(found.values()):
        raise ReportError(
            f"{root}: no results found (looked for pe_tables.*, sweep folders, capture-time stores, "
            "training runs, leaderboards, experiments, figures); run `make demo` or a farm command first"
        )
    body = []
    for key, title, command in SECTIONS:
        content = found[key]
        if content:
            body.append(f"<h2>{html.escape(title)}</h2>{content}")
        else:
            body.append(f"<h2>{html.escape(title)}</h2><p class=missing>No data in this folder: "
                        f"<code>{html.escape(command)}</code> would produce it.</p>")
    body += [f"<h2>{html.escape(title)}</h2>{found[key]}" for key, title in OPTIONAL_SECTIONS if found[key]]
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    return (
        "<!doctype html><html lang=en><head><meta charset=utf-8>"
        "<meta name=viewport content='width=device-width,initial-scale=1'>"
        f"<title>swarm-farm report: {html.escape(root.name)}</title>"
        f"<style>{CSS}</style>{SELF_CHECK}</head><body>"
        f"<h1>swarm-farm report</h1><p class=src>{html.escape(str(root.resolve()))} &middot; generated {stamp} "
        f"&middot; engine {html.escape(ENGINE_VERSION)}</p><p id=selfcheck></p>"
        + "".join(body)
        + "</body></html>"
    )


def write_report(results_dir, out=None) -> Path:
    """Build the report of results_dir and write it atomically; returns its path.

    out: the page's path (default results_dir/report.html). Bad input raises ReportError
    and leaves no file.
    """
    from farm.core.output import atomic_write_bytes, check_writable_file

    path = Path(out) if out else Path(results_dir) / "report.html"
    if path.exists() and path.is_dir():
        raise ReportError(f"-o: {path} is a folder")
    if out:  # before the page is built: a read-only place is found now (results_dir's is build_report's)
        try:
            check_writable_file(path, "-o")
        except SwarmFarmError as e:
            raise ReportError(str(e)) from None
    page = build_report(results_dir)
    atomic_write_bytes(path, page.encode())
    return path
