"""The Grafana dashboard and Prometheus config in dashboards/ (static checks, no network).

`dashboard_metric_names()` is also used by the live-sweep test, which checks that a
real sweep exports every farm metric the dashboard queries.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from farm.metrics import EXPORTED

DASHBOARDS = Path(__file__).resolve().parent.parent / "dashboards"
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
    ("sum(rate(ray_swarm_farm_service_hits_total[1m])) / (sum(rate(ray_swarm_farm_service_hits_total[1m]))"
     " + sum(rate(ray_swarm_farm_service_misses_total[1m])))",
     {"ray_swarm_farm_service_hits_total", "ray_swarm_farm_service_misses_total"}),
])
def test_metric_names_extractor(expr, names):
    assert metric_names(expr) == names


# --- the dashboard ----------------------------------------------------------------------


def test_dashboard_identity_and_variables():
    d = load_dashboard()
    assert d["uid"] == "swarm-farm" and d["title"] == "swarm-farm"
    assert 36 <= d["schemaVersion"] <= 41
    variables = {v["name"]: v for v in d["templating"]["list"]}
    ds = variables["datasource"]
    assert ds["type"] == "datasource" and ds["query"] == "prometheus"
    sweep = variables["sweep"]
    assert sweep["type"] == "query" and sweep["includeAll"] is True
    query = sweep["query"]["query"] if isinstance(sweep["query"], dict) else sweep["query"]
    assert query == "label_values(ray_swarm_farm_games_simulated_total, sweep)"
    assert sweep["datasource"]["uid"] == "${datasource}"


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
        assert p["type"] in {"timeseries", "stat"}, p["title"]
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


def test_exported_split_into_sweep_and_service_metrics():
    assert SERVICE_METRICS and SWEEP_METRICS
    assert SERVICE_METRICS | SWEEP_METRICS == set(EXPORTED)


def test_farm_panels_filter_by_sweep():
    """Every selector of a sweep-labelled farm metric filters by `$sweep`; service metrics
    (no `sweep` label) never do, or picking a sweep would blank their panels."""
    for expr in panel_exprs():
        names = metric_names(expr)
        for name in names & SWEEP_METRICS:
            selectors = re.findall(re.escape(name) + r"(?![A-Za-z0-9_:])(\{[^{}]*\})?", expr)
            assert selectors and all('sweep=~"$sweep"' in sel for sel in selectors), expr
        for name in names & SERVICE_METRICS:
            assert not re.search(re.escape(name) + r"\{[^{}]*\bsweep\b", expr), expr
            assert "$sweep" not in expr and not re.search(r"\bby\s*\([^()]*\bsweep\b", expr), expr


def test_service_row_below_the_others():
    panels = list(iter_panels())
    rows = [p for p in panels if p["type"] == "row"]
    service_rows = [r for r in rows if r["title"].startswith("Capture-time service")]
    assert len(service_rows) == 1
    row = service_rows[0]
    assert row["id"] >= 40 and row["gridPos"]["y"] == max(r["gridPos"]["y"] for r in rows)
    service_panels = [p for p in panels if p["type"] != "row" and metric_names(" ".join(
        t["expr"] for t in p["targets"])) & SERVICE_METRICS]
    assert service_panels
    others_bottom = max(p["gridPos"]["y"] + p["gridPos"]["h"] for p in panels
                        if p["id"] < 40)
    assert row["gridPos"]["y"] >= others_bottom
    for p in service_panels:
        assert p["id"] > row["id"] and p["gridPos"]["y"] > row["gridPos"]["y"], p["title"]


def test_farm_metric_names_match_exported():
    used = dashboard_metric_names()
    unknown = used - set(EXPORTED)
    assert not unknown, f"dashboard queries farm metrics not in farm.metrics.EXPORTED: {sorted(unknown)}"
    unused = set(EXPORTED) - used
    assert not unused, f"farm.metrics.EXPORTED names no panel queries: {sorted(unused)}"


def test_ray_core_metrics_are_queried():
    names = all_metric_names()
    for name in ("ray_node_cpu_utilization", "ray_node_mem_used", "ray_object_store_memory", "ray_tasks",
                 "ray_cluster_active_nodes"):
        assert name in names


# --- the Prometheus config ------------------------------------------------------------------


def test_prometheus_config_uses_ray_service_discovery():
    cfg = yaml.safe_load(PROMETHEUS_YML.read_text())
    assert cfg["global"]["scrape_interval"] == "5s"
    jobs = {job["job_name"]: job for job in cfg["scrape_configs"]}
    files = [f for sd in jobs["ray"]["file_sd_configs"] for f in sd["files"]]
    assert any(Path(f).name == DISCOVERY_FILE for f in files), files
