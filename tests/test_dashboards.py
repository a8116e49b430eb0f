"""The Grafana dashboard and Prometheus config in dashboards/: what they query exists.

Farm metric names are checked against the metrics farm/ defines (farm.runtime.metrics.EXPORTED and
the Counter/Gauge calls themselves), Ray's metric and label names against a live local Ray's
Prometheus endpoint, label values against Ray's task states and farm's functions, the
service-discovery file against Ray's constant. No literal of the files is pinned.

`dashboard_metric_names()` is also used by the live-sweep test, which checks that a
real sweep exports every farm metric the dashboard queries.
"""

from __future__ import annotations

import ast
import json
import os
import re
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from farm.runtime.metrics import EXPORTED

ROOT = Path(__file__).resolve().parent.parent
DASHBOARDS = ROOT / "dashboards"
DASHBOARD_JSON = DASHBOARDS / "grafana_swarm_farm.json"
PROMETHEUS_YML = DASHBOARDS / "prometheus.yml"
DISCOVERY_FILE = "prom_metrics_service_discovery.json"
FARM_PREFIX = "ray_swarm_farm_"
# The capture-time service is shared by all sweeps and trainers: its metrics carry no
# `sweep` label, so the `$sweep` filter applies only to the other farm metrics.
SERVICE_PREFIX = "ray_swarm_farm_service_"
SERVICE_METRICS = frozenset(n for n in EXPORTED if n.startswith(SERVICE_PREFIX))
SWEEP_METRICS = frozenset(EXPORTED) - SERVICE_METRICS

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|\'(?:[^\'\\]|\\.)*\'|`[^`]*`')
_MATCHERS = re.compile(r"\{[^{}]*\}")  # label matchers: {sweep=~"$sweep"}
_RANGES = re.compile(r"\[[^\[\]]*\]")  # range selectors: [1m], [$__range]
_GROUPING = re.compile(r"\b(?:by|without|on|ignoring|group_left|group_right)\s*\([^()]*\)")
_LABEL_VALUES = re.compile(r"\blabel_values\s*\(\s*([^,()]*(?:\{[^{}]*\})?)\s*,[^()]*\)")
_METRIC = re.compile(r"(?<![A-Za-z0-9_:])ray_[A-Za-z0-9_:]*")
_SELECTOR = re.compile(r"(?<![A-Za-z0-9_:])(ray_[A-Za-z0-9_:]*)\s*\{([^{}]*)\}")
_MATCHER = re.compile(r'([A-Za-z_][A-Za-z0-9_]*)\s*(=~|!~|!=|=)\s*"((?:[^"\\]|\\.)*)"')
_VARIABLE = re.compile(r"\$\{?([A-Za-z_][A-Za-z0-9_]*)")
TARGET_LABELS = {"instance", "job"}  # attached by Prometheus when it scrapes, not by Ray


def load_dashboard() -> dict:
    return json.loads(DASHBOARD_JSON.read_text())


def iter_panels(dashboard: dict | None = None):
    """Every panel, rows' nested panels (collapsed rows) included, rows themselves too."""
    dashboard = load_dashboard() if dashboard is None else dashboard
    for panel in dashboard.get("panels", []):
        yield panel
        yield from panel.get("panels", [])


def panel_exprs(dashboard: dict | None = None) -> list[str]:
    return [t["expr"] for p in iter_panels(dashboard) for t in p.get("targets", []) if t.get("expr")]


def variable_queries(dashboard: dict | None = None) -> list[str]:
    dashboard = load_dashboard() if dashboard is None else dashboard
    out = []
    for var in dashboard.get("templating", {}).get("list", []):
        if var.get("type") != "query":
            continue
        q = var.get("query")
        out.append(q.get("query", "") if isinstance(q, dict) else (q or ""))
    return out


def metric_names(expr: str) -> set[str]:
    """Metric names (identifiers starting with `ray_`) used by a PromQL expression or a
    Grafana label_values() query; label names, label values and durations are skipped."""
    expr = _LABEL_VALUES.sub(r"\1", expr)  # label_values(metric{...}, label) -> metric{...}
    expr = _STRING.sub("", expr)
    expr = _MATCHERS.sub(" ", expr)
    expr = _RANGES.sub(" ", expr)
    expr = _GROUPING.sub(" ", expr)
    return set(_METRIC.findall(expr))


def all_metric_names(dashboard: dict | None = None) -> set[str]:
    dashboard = load_dashboard() if dashboard is None else dashboard
    names: set[str] = set()
    for expr in panel_exprs(dashboard) + variable_queries(dashboard):
        names |= metric_names(expr)
    return names


def dashboard_metric_names() -> set[str]:
    """The `ray_swarm_farm_*` names (as Prometheus sees them) that the dashboard queries."""
    return {n for n in all_metric_names() if n.startswith(FARM_PREFIX)}


def selectors(expr: str) -> list[tuple[str, list[tuple[str, str, str]]]]:
    """(metric, [(label, op, value), ...]) of every `metric{...}` selector of an expression."""
    expr = _LABEL_VALUES.sub(r"\1", expr)
    return [(m.group(1), _MATCHER.findall(m.group(2))) for m in _SELECTOR.finditer(expr)]


def grouping_labels(expr: str) -> set[str]:
    """Labels of `by (...)` / `without (...)` / `on (...)` / `ignoring (...)` clauses."""
    out = set()
    for m in re.finditer(r"\b(?:by|without|on|ignoring)\s*\(([^()]*)\)", expr):
        out |= {x.strip() for x in m.group(1).split(",") if x.strip()}
    return out


def defined_metrics() -> dict[str, tuple[str, tuple[str, ...]]]:
    """Prometheus name -> (kind, tag keys) of every Counter / Gauge / Histogram farm/ creates
    (Ray prefixes `ray_`; a Counter is exported as `<name>_total`), read from the source."""
    import farm.runtime.metrics

    out = {}
    for path in (ROOT / "farm").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in {"Counter", "Gauge", "Histogram"} and node.args
                    and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
                continue
            tags: tuple[str, ...] = ()
            for kw in node.keywords:
                if kw.arg == "tag_keys":
                    tags = (getattr(farm.runtime.metrics, kw.value.id) if isinstance(kw.value, ast.Name)
                            else tuple(ast.literal_eval(kw.value)))
            name = "ray_" + node.args[0].value + ("_total" if node.func.id == "Counter" else "")
            out[name] = (node.func.id, tuple(tags))
    return out


# --- the extractor itself -------------------------------------------------------------


@pytest.mark.parametrize("expr, names", [
    ('sum by (sweep) (rate(ray_swarm_farm_games_simulated_total{sweep=~"$sweep"}[1m]))',
     {"ray_swarm_farm_games_simulated_total"}),
    ('sum(ray_node_cpu_utilization * ray_node_cpu_count / 100)', {"ray_node_cpu_utilization", "ray_node_cpu_count"}),
    ('sum by (ray_io_cluster) (ray_tasks{ray_io_cluster="ray_x", State!~"FINISHED"})', {"ray_tasks"}),
    ('max_over_time(ray_a_total{sweep=~"$sweep"}[$__range]) / on (ray_io_cluster) ray_b', {"ray_a_total", "ray_b"}),
    ("label_values(ray_swarm_farm_games_simulated_total, sweep)", {"ray_swarm_farm_games_simulated_total"}),
    ("label_values(ray_node_cpu_count{SessionName=~\"$s\"}, ray_io_cluster)", {"ray_node_cpu_count"}),
    ("vector(1)", set()),
    ('sum by (State) (ray_tasks{Name=~".*_remote_shard", IsRetry!="0"})', {"ray_tasks"}),
    ("sum(rate(ray_swarm_farm_service_hits_total[1m])) / (sum(rate(ray_swarm_farm_service_hits_total[1m]))"
     " + sum(rate(ray_swarm_farm_service_misses_total[1m])))",
     {"ray_swarm_farm_service_hits_total", "ray_swarm_farm_service_misses_total"}),
])
def test_metric_names_extractor(expr, names):
    assert metric_names(expr) == names


# --- the dashboard ----------------------------------------------------------------------


def test_dashboard_variables_are_defined_and_list_real_label_values():
    """Every $variable the dashboard uses is defined (or a Grafana global); the datasource
    variable picks Prometheus (the targets are PromQL); each query variable lists a label
    the farm's code really attaches to the metric it names; a multi-value variable is only
    matched with a regex (`=~`), the form Grafana's multi-select and All need."""
    d = load_dashboard()
    variables = {v["name"]: v for v in d["templating"]["list"]}
    used = set(_VARIABLE.findall(json.dumps(d.get("panels", [])))) | set(_VARIABLE.findall(json.dumps(d["templating"])))
    undefined = {v for v in used if not v.startswith("__")} - set(variables)
    assert not undefined, f"variables used but not defined: {sorted(undefined)}"
    datasources = [v for v in variables.values() if v["type"] == "datasource"]
    assert datasources and all(v["query"] == "prometheus" for v in datasources)
    code = defined_metrics()
    for var in variables.values():
        if var["type"] != "query":
            continue
        q = var["query"]["query"] if isinstance(var["query"], dict) else var["query"]
        m = re.fullmatch(r"\s*label_values\(\s*([A-Za-z0-9_:]+)\s*(?:\{[^{}]*\})?\s*,\s*(\w+)\s*\)\s*", q)
        assert m, f"variable {var['name']}: unexpected query {q!r}"
        metric, label = m.groups()
        assert metric in code, f"variable {var['name']} lists values of {metric}, which farm/ never creates"
        assert label in code[metric][1], f"{metric} carries no label {label!r} (tag keys {code[metric][1]})"
        if var.get("multi") or var.get("includeAll"):
            for expr in panel_exprs(d):
                for _, matchers in selectors(expr):
                    for _, op, value in matchers:
                        if f"${var['name']}" in value or f"${{{var['name']}}}" in value:
                            assert op in {"=~", "!~"}, f"{expr}: multi-value ${var['name']} needs =~"


def test_panels_have_datasource_targets_ids_and_positions():
    panels = list(iter_panels())
    ids = [p["id"] for p in panels]
    assert len(ids) == len(set(ids)), "panel ids must be unique"
    data_panels = [p for p in panels if p["type"] != "row"]
    assert data_panels
    for p in panels:
        pos = p["gridPos"]
        assert {"h", "w", "x", "y"} <= set(pos) and 0 <= pos["x"] and pos["x"] + pos["w"] <= 24, p["title"]
    for p in data_panels:
        assert p["datasource"] == {"type": "prometheus", "uid": "${datasource}"}, p["title"]
        assert p.get("targets"), f"panel {p['title']!r} has no targets"
        ref_ids = [t["refId"] for t in p["targets"]]
        assert len(ref_ids) == len(set(ref_ids)), p["title"]
        for t in p["targets"]:
            assert isinstance(t.get("expr"), str) and t["expr"].strip(), f"empty expr in {p['title']!r}"
            assert t.get("datasource", p["datasource"])["uid"] == "${datasource}", p["title"]


def test_panels_do_not_overlap():
    cells = {}
    for p in iter_panels():
        pos = p["gridPos"]
        for x in range(pos["x"], pos["x"] + pos["w"]):
            for y in range(pos["y"], pos["y"] + pos["h"]):
                assert (x, y) not in cells, f"{p['title']!r} overlaps {cells[(x, y)]!r}"
                cells[(x, y)] = p["title"]


def test_exported_are_the_metrics_the_code_creates_with_their_labels():
    """farm.runtime.metrics.EXPORTED lists exactly the metrics farm/ creates, and the split the
    dashboard relies on holds in the code: sweep metrics carry the `sweep` tag, service
    metrics carry none."""
    code = defined_metrics()
    assert set(code) == set(EXPORTED), f"created {sorted(set(code) - set(EXPORTED))}, " \
                                       f"listed only {sorted(set(EXPORTED) - set(code))}"
    assert SERVICE_METRICS and SWEEP_METRICS
    assert {n for n, (_, tags) in code.items() if "sweep" in tags} == SWEEP_METRICS
    assert {n for n, (_, tags) in code.items() if not tags} == SERVICE_METRICS


def test_farm_panels_filter_by_sweep():
    """Every selector of a sweep-labelled farm metric filters by `$sweep`; service metrics
    (no `sweep` label) never do, or picking a sweep would blank their panels."""
    for expr in panel_exprs():
        names = metric_names(expr)
        for name in names & SWEEP_METRICS:
            selectors_ = re.findall(re.escape(name) + r"(?![A-Za-z0-9_:])(\{[^{}]*\})?", expr)
            assert selectors_ and all('sweep=~"$sweep"' in sel for sel in selectors_), expr
        for name in names & SERVICE_METRICS:
            assert not re.search(re.escape(name) + r"\{[^{}]*\bsweep\b", expr), expr
            assert "$sweep" not in expr and not re.search(r"\bby\s*\([^()]*\bsweep\b", expr), expr


def test_farm_metric_names_match_exported():
    used = dashboard_metric_names()
    unknown = used - set(EXPORTED)
    assert not unknown, f"dashboard queries farm metrics not in farm.runtime.metrics.EXPORTED: {sorted(unknown)}"
    unused = set(EXPORTED) - used
    assert not unused, f"farm.runtime.metrics.EXPORTED names no panel queries: {sorted(unused)}"


def test_label_values_matched_exist():
    """Values the dashboard matches Ray's task metrics on are real: task states are Ray's
    TaskStatus names, task-name patterns match a function farm/ defines."""
    from ray.core.generated.common_pb2 import TaskStatus

    functions = {n.name for p in (ROOT / "farm").rglob("*.py") for n in ast.walk(ast.parse(p.read_text()))
                 if isinstance(n, ast.FunctionDef)}
    checked = 0
    for expr in panel_exprs():
        for metric, matchers in selectors(expr):
            for label, op, value in matchers:
                if metric == "ray_tasks" and label == "State":
                    unknown = {v for v in value.split("|") if v} - set(TaskStatus.keys())
                    assert not unknown, f"{expr}: not Ray task states: {unknown}"
                    checked += 1
                elif metric == "ray_tasks" and label == "Name" and op == "=~":
                    assert any(re.fullmatch(value, f) for f in functions), f"{expr}: no farm function matches {value!r}"
                    checked += 1
    assert checked


def _scrape(port: int) -> dict[str, set[str]]:
    """metric name -> label names of a Prometheus text endpoint."""
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    out: dict[str, set[str]] = {}
    for m in re.finditer(r"^([A-Za-z_:][A-Za-z0-9_:]*)(\{[^}]*\})?\s", text, re.M):
        out.setdefault(m.group(1), set()).update(re.findall(r'([A-Za-z_][A-Za-z0-9_]*)="', m.group(2) or ""))
    return out


@pytest.mark.ray
def test_ray_metrics_and_labels_the_dashboard_queries_are_exported_by_ray(ray_local):
    """On a live local Ray (conftest's ray_local, its Prometheus endpoint), every Ray metric
    the dashboard queries is exported, with every label the dashboard matches or groups on."""
    import ray

    @ray.remote
    def _remote_shard():  # a task, so that the task metrics exist
        return 1

    assert ray.get([_remote_shard.remote() for _ in range(4)]) == [1] * 4
    exprs = panel_exprs() + variable_queries()
    core = {n for e in exprs for n in metric_names(e)} - set(EXPORTED)
    assert core
    deadline = time.time() + 60
    while True:
        exported = _scrape(ray_local)
        missing = core - set(exported)
        if not missing or time.time() > deadline:
            break
        time.sleep(1)
    assert not missing, f"the dashboard queries metrics Ray does not export: {sorted(missing)}"
    for expr in exprs:
        metrics = metric_names(expr) & core
        if not metrics:
            continue
        for metric, matchers in selectors(expr):
            if metric in core:
                unknown = {lbl for lbl, _, _ in matchers} - exported[metric] - TARGET_LABELS
                assert not unknown, f"{expr}: {metric} has no labels {unknown} (has {sorted(exported[metric])})"
        if metrics == metric_names(expr):  # only Ray metrics: group labels must be on one of them
            have = set().union(*(exported[m] for m in metrics)) | TARGET_LABELS
            assert grouping_labels(expr) <= have, f"{expr}: grouping by labels Ray does not attach"


# --- the Prometheus config ------------------------------------------------------------------


def test_prometheus_config_reads_rays_service_discovery_file(monkeypatch):
    """The scrape config parses and reads the file Ray's head writes its nodes' metrics
    endpoints to: Ray's PROMETHEUS_SERVICE_DISCOVERY_FILE in Ray's default temp dir."""
    import ray._private.ray_constants as rc
    from ray._common.utils import get_default_ray_temp_dir

    monkeypatch.delenv("TMPDIR", raising=False)  # the default on a head node
    cfg = yaml.safe_load(PROMETHEUS_YML.read_text())
    jobs = {job["job_name"]: job for job in cfg["scrape_configs"]}
    assert len(jobs) == len(cfg["scrape_configs"])
    files = [f for job in jobs.values() for sd in job.get("file_sd_configs", []) for f in sd["files"]]
    assert os.path.join(get_default_ray_temp_dir(), rc.PROMETHEUS_SERVICE_DISCOVERY_FILE) in files, files


def test_repo_paths_named_in_dashboards_readme_exist():
    text = (DASHBOARDS / "README.md").read_text()
    named = set(re.findall(r"(?<![\w.~/-])(?:dashboards|farm|tests|deploy)/[\w./-]*\w", text))
    named |= {f"dashboards/{n}" for n in re.findall(r"`([\w.-]+\.(?:json|ya?ml))`", text)}
    assert named
    missing = sorted(n for n in named if not (ROOT / n).exists())
    assert not missing, missing
