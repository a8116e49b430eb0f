"""deploy/: the image, the KubeRay manifests and the `ray up` config hold what a cluster needs.

Static checks only: no network, docker or kubectl.
"""

from __future__ import annotations

import copy
import re
import shlex
import tomllib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
KUBERAY = DEPLOY / "kuberay"

SHM = "/dev/shm"
METRICS_PORT = 8080
HEAD_PORTS = {6379, 8265, 10001, METRICS_PORT}


# ----- helpers ---------------------------------------------------------------------------------
def load(path: Path) -> dict:
    doc = yaml.safe_load(path.read_text())
    assert isinstance(doc, dict), f"{path}: not a YAML mapping"
    return doc


def project_version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def image_tag() -> str:
    return f"swarm-farm:{project_version()}"


def dockerfile_lines() -> list[str]:
    """Instructions of deploy/Dockerfile with continuation lines joined, comments dropped."""
    text = (DEPLOY / "Dockerfile").read_text()
    text = re.sub(r"\\\n", " ", text)
    return [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def dockerfile_from() -> tuple[str, str]:
    froms = [ln for ln in dockerfile_lines() if ln.upper().startswith("FROM ")]
    assert len(froms) == 1, f"expected one FROM, got {froms}"
    m = re.fullmatch(r"FROM\s+rayproject/ray:(\d+\.\d+\.\d+)-py(\d+)(-cpu)?(\s+AS\s+\S+)?", froms[0], re.I)
    assert m, f"FROM must be an official rayproject/ray CPU image: {froms[0]}"
    return m.group(1), m.group(2)


def quantity(value) -> float:
    """A Kubernetes quantity ('500m', '4', '8Gi', '1G') as a number."""
    s = str(value)
    units = {"m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12,
             "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
    m = re.fullmatch(r"([0-9.]+)([A-Za-z]*)", s)
    assert m and (m.group(2) in units or m.group(2) == ""), f"not a quantity: {value!r}"
    return float(m.group(1)) * units.get(m.group(2), 1)


def ray_cluster_specs() -> list[tuple[str, dict]]:
    return [
        ("raycluster.yaml", load(KUBERAY / "raycluster.yaml")["spec"]),
        ("rayjob.yaml", load(KUBERAY / "rayjob.yaml")["spec"]["rayClusterSpec"]),
    ]


def groups(spec: dict) -> list[tuple[str, dict]]:
    """(name, group spec) of the head group and every worker group."""
    out = [("head", spec["headGroupSpec"])]
    out += [(f"worker group {g.get('groupName')}", g) for g in spec["workerGroupSpecs"]]
    return out


def ray_container(group: dict) -> dict:
    # KubeRay runs Ray in the first container of the pod template.
    return group["template"]["spec"]["containers"][0]


GROUP_CASES = [
    pytest.param(fname, gname, group, id=f"{fname}:{gname}")
    for fname, spec in ray_cluster_specs()
    for gname, group in groups(spec)
]


# ----- Dockerfile ------------------------------------------------------------------------------
def test_dockerfile_base_image_matches_installed_ray():
    import ray

    version, py = dockerfile_from()
    assert version.split(".")[:2] == ray.__version__.split(".")[:2], (
        f"image Ray {version} vs installed ray {ray.__version__}"
    )
    assert py == "311", "the project targets Python 3.11 (py311 image)"


def test_dockerfile_installs_the_project_with_cpu_constraints():
    lines = dockerfile_lines()
    copies = [ln for ln in lines if ln.upper().startswith("COPY ")]
    assert any("constraints-cpu.txt" in ln for ln in copies), "constraints-cpu.txt is not copied"
    assert any(re.search(r"\s\.\s+(/app|\.)/?$", ln) for ln in copies), "the repo is not copied"
    installs = [ln for ln in lines if ln.upper().startswith("RUN ") and "pip install" in ln]
    project = [ln for ln in installs if re.search(r"-c\s+constraints-cpu\.txt\b.*\s\.(\s|$)", ln)]
    assert project, f"no `pip install -c constraints-cpu.txt ... .` among {installs}"
    assert all("--no-cache-dir" in ln for ln in installs)
    workdirs = [ln.split()[1] for ln in lines if ln.upper().startswith("WORKDIR ")]
    assert workdirs and workdirs[-1] == "/app"


def test_dockerfile_leaves_the_start_command_to_kuberay():
    for ln in dockerfile_lines():
        assert not ln.upper().startswith(("CMD ", "CMD[", "ENTRYPOINT")), f"{ln}: KubeRay supplies `ray start`"


def test_dockerignore_keeps_what_the_image_needs_and_drops_the_venv():
    rules = [ln.strip() for ln in (DEPLOY / "Dockerfile.dockerignore").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    assert rules[0] == "*", "allowlist expected: exclude everything first"
    kept = {r[1:].rstrip("/") for r in rules if r.startswith("!")}
    needed = {"pyproject.toml", "README.md", "constraints-cpu.txt", "configs"}
    needed |= {p.rstrip("*") for p in tomllib.loads((ROOT / "pyproject.toml").read_text())
               ["tool"]["setuptools"]["packages"]["find"]["include"]}
    assert needed <= kept, f"missing from the build context: {needed - kept}"
    assert not {".venv", ".git", "results"} & kept


# ----- KubeRay ---------------------------------------------------------------------------------
def test_kuberay_kinds():
    assert load(KUBERAY / "raycluster.yaml")["apiVersion"] == "ray.io/v1"
    assert load(KUBERAY / "raycluster.yaml")["kind"] == "RayCluster"
    assert load(KUBERAY / "rayjob.yaml")["apiVersion"] == "ray.io/v1"
    assert load(KUBERAY / "rayjob.yaml")["kind"] == "RayJob"
    pvc = load(KUBERAY / "results-pvc.yaml")
    assert (pvc["apiVersion"], pvc["kind"]) == ("v1", "PersistentVolumeClaim")


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_ray_version_is_the_images(fname, spec):
    assert spec["rayVersion"] == dockerfile_from()[0]


def test_rayjob_cluster_is_the_raycluster():
    (_, cluster), (_, job_cluster) = ray_cluster_specs()
    assert job_cluster == cluster, "rayjob.yaml's rayClusterSpec drifted from raycluster.yaml's spec"


@pytest.mark.parametrize("fname,gname,group", GROUP_CASES)
def test_every_container_runs_the_project_image(fname, gname, group):
    pod = group["template"]["spec"]
    for c in pod.get("initContainers", []) + pod["containers"]:
        assert c.get("image") == image_tag(), f"{c.get('name')}: image {c.get('image')!r}"


@pytest.mark.parametrize("fname,gname,group", GROUP_CASES)
def test_ray_container_has_cpu_and_memory_requests_and_limits(fname, gname, group):
    res = ray_container(group)["resources"]
    for kind in ("requests", "limits"):
        assert {"cpu", "memory"} <= set(res.get(kind, {})), f"{kind}: {res.get(kind)}"
    for r in ("cpu", "memory"):
        assert quantity(res["requests"][r]) <= quantity(res["limits"][r])
    num_cpus = group["rayStartParams"].get("num-cpus")
    assert num_cpus is not None, "set num-cpus so Ray does not guess from the node"
    assert 0 <= int(num_cpus) <= quantity(res["limits"]["cpu"])


@pytest.mark.parametrize("fname,gname,group", GROUP_CASES)
def test_shared_memory_volume_backs_the_object_store(fname, gname, group):
    pod = group["template"]["spec"]
    shm_mounts = [m for m in ray_container(group).get("volumeMounts", []) if m["mountPath"] == SHM]
    assert len(shm_mounts) == 1, f"no {SHM} mount"
    volume = {v["name"]: v for v in pod["volumes"]}[shm_mounts[0]["name"]]
    assert volume["emptyDir"]["medium"] == "Memory"
    limit = quantity(volume["emptyDir"]["sizeLimit"])
    assert limit < quantity(ray_container(group)["resources"]["limits"]["memory"])
    store = group["rayStartParams"].get("object-store-memory")
    assert store is not None and int(store) < limit, "the object store must fit in /dev/shm"


@pytest.mark.parametrize("fname,gname,group", GROUP_CASES)
def test_ray_start_params_export_metrics(fname, gname, group):
    params = group["rayStartParams"]
    assert all(isinstance(v, str) for v in params.values()), "KubeRay wants string values"
    assert params.get("metrics-export-port") == str(METRICS_PORT)
    ports = {p["containerPort"] for p in ray_container(group).get("ports", [])}
    assert METRICS_PORT in ports
    if gname == "head":
        assert params.get("dashboard-host") == "0.0.0.0"
        assert HEAD_PORTS <= ports, f"head ports {ports}"


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_worker_group_scaling_bounds(fname, spec):
    assert spec["workerGroupSpecs"], "no worker group"
    for g in spec["workerGroupSpecs"]:
        assert g["groupName"]
        assert 0 <= g["minReplicas"] <= g["replicas"] <= g["maxReplicas"]


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_head_mounts_the_results_volume(fname, spec):
    head = spec["headGroupSpec"]
    mounts = [m for m in ray_container(head).get("volumeMounts", []) if m["mountPath"] == "/data"]
    assert len(mounts) == 1
    volume = {v["name"]: v for v in head["template"]["spec"]["volumes"]}[mounts[0]["name"]]
    if "persistentVolumeClaim" in volume:
        claim = volume["persistentVolumeClaim"]["claimName"]
        assert claim == load(KUBERAY / "results-pvc.yaml")["metadata"]["name"]
    else:
        assert "emptyDir" in volume
    # the image's user (ray, gid 100) must be able to write to the volume
    assert head["template"]["spec"].get("securityContext", {}).get("fsGroup") == 100


def test_rayjob_runs_a_sweep_of_an_existing_config_into_the_results_volume():
    spec = load(KUBERAY / "rayjob.yaml")["spec"]
    assert spec["submissionMode"] == "K8sJobMode"
    assert spec["shutdownAfterJobFinishes"] is True
    assert isinstance(spec["ttlSecondsAfterFinished"], int) and spec["ttlSecondsAfterFinished"] >= 0
    entry = spec["entrypoint"]
    assert entry.startswith("farm sweep ")
    args = shlex.split(entry)[2:]
    config = args[0]
    assert config.startswith("configs/") and config.endswith((".yaml", ".yml"))
    assert (ROOT / config).is_file(), f"{config} is not in the repo"
    out = args[args.index("--out") + 1]
    assert out.startswith("/data/"), "results must land on the /data volume, which outlives the cluster"
    # relative config paths resolve against the job's working dir: the image's /app
    runtime_env = yaml.safe_load(spec["runtimeEnvYAML"])
    assert runtime_env["working_dir"] == "/app"
    assert {"workers/", "farm/"} <= set(runtime_env["excludes"])  # the installed, precompiled package runs


# ----- ray up ----------------------------------------------------------------------------------
def test_cluster_yaml_has_what_ray_up_needs():
    c = load(DEPLOY / "cluster.yaml")
    assert c["cluster_name"]
    assert c["provider"]["type"] == "local"
    assert c["max_workers"] <= len(c["provider"]["worker_ips"])
    assert c["docker"]["image"] == image_tag()
    assert any(o.startswith("--shm-size") for o in c["docker"]["run_options"])
    head = " ; ".join(c["head_start_ray_commands"])
    for flag in ("ray start --head", "--port=6379", "--dashboard-host=0.0.0.0",
                 f"--metrics-export-port={METRICS_PORT}", "--autoscaling-config=~/ray_bootstrap_config.yaml"):
        assert flag in head, f"head_start_ray_commands lack {flag}"
    worker = " ; ".join(c["worker_start_ray_commands"])
    for flag in ("ray start --address=$RAY_HEAD_IP:6379", f"--metrics-export-port={METRICS_PORT}"):
        assert flag in worker, f"worker_start_ray_commands lack {flag}"
    assert any("pip install" in cmd for cmd in c["setup_commands"])
    for local in c["file_mounts"].values():
        assert (ROOT / local).exists(), f"file mount source {local} (relative to the repo root)"


def test_cluster_yaml_passes_rays_own_schema():
    from ray.autoscaler._private.util import prepare_config, validate_config

    validate_config(prepare_config(copy.deepcopy(load(DEPLOY / "cluster.yaml"))))


# ----- docs ------------------------------------------------------------------------------------
def test_readme_builds_the_tag_the_manifests_use():
    text = (DEPLOY / "README.md").read_text()
    assert f"docker build -f deploy/Dockerfile -t {image_tag()} ." in text
    assert image_tag() in (DEPLOY / "Dockerfile").read_text()


def test_configs_named_in_deploy_exist():
    texts = [p.read_text() for p in DEPLOY.rglob("*") if p.is_file()]
    named = {m for t in texts for m in re.findall(r"\bconfigs/[\w.-]+\.ya?ml\b", t)}
    assert named, "deploy/ names no config"
    missing = sorted(n for n in named if not (ROOT / n).is_file())
    assert not missing, f"named in deploy/ but not in the repo: {missing}"
