"""deploy/: the image, the KubeRay manifests and the `ray up` config hold what a cluster needs.

What is checked is meaning, not spelling: the files parse, the manifests have what KubeRay
needs and agree with each other and with the Dockerfile, and every command, image, config,
option and path they (and deploy/README.md, dashboards/README.md) name exists: `farm`
commands parse with farm.cli's parser and their sweep configs load, `ray` commands parse
with Ray's own CLI, the image is the one the documented `docker build` makes.

Static checks only: no network, docker or kubectl. Real `ray start` / `ray job submit`
runs are in tests/test_cluster_cli.py.
"""

from __future__ import annotations

import ast
import copy
import importlib
import json
import re
import shlex
import tomllib
from pathlib import Path, PurePosixPath

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
KUBERAY = DEPLOY / "kuberay"
SHM = "/dev/shm"  # where Ray puts its object store


# ----- helpers ---------------------------------------------------------------------------------
def load(path: Path) -> dict:
    doc = yaml.safe_load(path.read_text())
    assert isinstance(doc, dict), f"{path}: not a YAML mapping"
    return doc


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def dockerfile_lines() -> list[str]:
    """Instructions of deploy/Dockerfile with continuation lines joined, comments dropped."""
    text = (DEPLOY / "Dockerfile").read_text()
    text = re.sub(r"\\\n", " ", text)
    return [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def dockerfile_from() -> tuple[str, str]:
    froms = [ln for ln in dockerfile_lines() if ln.upper().startswith("FROM ")]
    assert len(froms) == 1, f"expected one FROM, got {froms}"
    m = re.fullmatch(r"FROM\s+rayproject/ray:(\d+\.\d+\.\d+)-py(\d)(\d+)(-cpu)?(\s+AS\s+\S+)?", froms[0], re.I)
    assert m, f"FROM must be an official rayproject/ray image: {froms[0]}"
    return m.group(1), f"{m.group(2)}.{m.group(3)}"


def dockerfile_workdir() -> str:
    workdirs = [ln.split()[1] for ln in dockerfile_lines() if ln.upper().startswith("WORKDIR ")]
    assert workdirs, "no WORKDIR"
    return workdirs[-1]


def quantity(value) -> float:
    """A Kubernetes quantity ('500m', '4', '8Gi', '1G') as a number."""
    s = str(value)
    units = {"m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9, "T": 1e12,
             "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40}
    m = re.fullmatch(r"([0-9.]+)([A-Za-z]*)", s)
    assert m and (m.group(2) in units or m.group(2) == ""), f"not a quantity: {value!r}"
    return float(m.group(1)) * units.get(m.group(2), 1)


def manifests() -> dict[str, dict]:
    return {p.name: load(p) for p in sorted(KUBERAY.glob("*.y*ml"))}


def of_kind(kind: str) -> list[tuple[str, dict]]:
    return [(name, doc) for name, doc in manifests().items() if doc.get("kind") == kind]


def ray_cluster_specs() -> list[tuple[str, dict]]:
    return ([(name, doc["spec"]) for name, doc in of_kind("RayCluster")]
            + [(name, doc["spec"]["rayClusterSpec"]) for name, doc in of_kind("RayJob")])


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


def ray_cli(argv: list[str]):
    """Parse a `ray ...` command line with Ray's own click CLI (raises click.UsageError on an
    unknown subcommand or option); returns (command path, parsed params)."""
    import click
    from ray.scripts.scripts import cli

    assert argv[0] == "ray", argv
    cmd, path, rest = cli, ["ray"], argv[1:]
    while isinstance(cmd, click.Group):
        assert rest, f"{shlex.join(argv)}: no subcommand"
        sub = cmd.get_command(None, rest[0])
        if sub is None:
            raise click.UsageError(f"no such command {' '.join(path)} {rest[0]}")
        cmd, path, rest = sub, path + [rest[0]], rest[1:]
    ctx = cmd.make_context(" ".join(path), list(rest), resilient_parsing=False)
    return path, ctx.params


def farm_cli(argv: list[str]):
    """Parse a `farm ...` command line with farm.cli's parser; a sweep's config must load."""
    from farm.cli import build_parser

    assert argv[0] == "farm", argv
    try:
        args = build_parser().parse_args(argv[1:])
    except SystemExit as e:  # argparse reports and exits on a bad command line
        raise AssertionError(f"`{shlex.join(argv)}` does not parse: exit {e.code}") from None
    if args.command == "sweep":
        from farm.games.sweep import load_sweep_config

        load_sweep_config(ROOT / args.config)
    return args


def _logical_lines(text: str) -> list[str]:
    return [ln.strip() for ln in re.sub(r"\\\n", " ", text).splitlines() if ln.strip()]


def _commands_in(text: str, kind: str) -> list[list[str]]:
    """`farm` and `ray` command lines of a README's bash blocks or of a file's comments."""
    if kind == "readme":
        lines = [ln for block in re.findall(r"```(?:bash|sh)\n(.*?)```", text, re.S) for ln in _logical_lines(block)]
    else:  # commands quoted in comments, continuation lines joined
        comments = "\n".join(m.group(1) for m in re.finditer(r"^\s*#(.*)$", text, re.M))
        lines = _logical_lines(comments)
    out = []
    for ln in lines:
        if not re.match(r"(farm|ray)\s", ln):
            continue
        argv = shlex.split(ln, comments=True)
        while argv and argv[-1] in {"&", "&&", ";"}:
            argv.pop()
        out.append(argv)
    return out


def documented_commands() -> list[tuple[str, list[str]]]:
    """(where, argv) of every `farm` / `ray` command deploy/ and dashboards/ tell you to run."""
    out = []
    for path in [DEPLOY / "README.md", ROOT / "dashboards" / "README.md"]:
        out += [(path.name, argv) for argv in _commands_in(path.read_text(), "readme")]
    for path in sorted(DEPLOY.rglob("*")):
        if path.is_file() and path.suffix in {".yaml", ".yml", ""}:
            out += [(path.name, argv) for argv in _commands_in(path.read_text(), "comments")]
    cluster = load(DEPLOY / "cluster.yaml")
    for key in ("head_start_ray_commands", "worker_start_ray_commands"):
        out += [(f"cluster.yaml:{key}", shlex.split(c)) for c in cluster[key]]
    for name, doc in of_kind("RayJob"):
        out.append((f"{name}:entrypoint", shlex.split(doc["spec"]["entrypoint"])))
    return out


def farm_commands() -> list[tuple[str, list[str]]]:
    """Every `farm` command, including the entrypoints of `ray job submit ... -- farm ...`."""
    out = []
    for where, argv in documented_commands():
        if argv[0] == "farm":
            out.append((where, argv))
        elif argv[:3] == ["ray", "job", "submit"] and "--" in argv:
            out.append((where, argv[argv.index("--") + 1:]))
    return out


def docker_build() -> dict:
    """The `docker build` command of deploy/README.md: {'file', 'tag', 'context'}."""
    builds = [shlex.split(ln) for ln in _logical_lines((DEPLOY / "README.md").read_text())
              if ln.startswith("docker build ")]
    assert len(builds) == 1, builds
    argv = builds[0]
    return {"file": argv[argv.index("-f") + 1], "tag": argv[argv.index("-t") + 1], "context": argv[-1]}


def constraint_files() -> list[str]:
    """Constraints files (`pip install -c FILE`) of the Dockerfile, except those made in /tmp."""
    out = []
    for ln in dockerfile_lines():
        for part in ln.split("&&"):
            if "pip install" in part:
                out += [c for c in re.findall(r"(?:^|\s)-c\s+(\S+)", part) if not c.startswith("/tmp/")]
    return out


def project_packages() -> set[str]:
    return {p.rstrip("*").rstrip(".") for p in pyproject()["tool"]["setuptools"]["packages"]["find"]["include"]}


def head_results_mounts(spec: dict) -> dict[str, dict]:
    """mountPath -> volume of the head's Ray container, except the shared-memory one."""
    head = spec["headGroupSpec"]
    volumes = {v["name"]: v for v in head["template"]["spec"]["volumes"]}
    return {m["mountPath"]: volumes[m["name"]] for m in ray_container(head).get("volumeMounts", [])
            if m["mountPath"] != SHM}


def under(path: str, root: str) -> bool:
    return PurePosixPath(root) in PurePosixPath(path).parents


# ----- Dockerfile ------------------------------------------------------------------------------
def test_dockerfile_base_image_matches_installed_ray_and_project_python():
    import ray
    from packaging.specifiers import SpecifierSet

    version, py = dockerfile_from()
    assert version.split(".")[:2] == ray.__version__.split(".")[:2], (
        f"image Ray {version} vs installed ray {ray.__version__}"
    )
    assert py in SpecifierSet(pyproject()["project"]["requires-python"]), f"image Python {py}"


def test_dockerfile_copies_existing_files_and_installs_the_project():
    lines = dockerfile_lines()
    copies = [shlex.split(ln)[1:] for ln in lines if ln.upper().startswith("COPY ")]
    for args in copies:
        *sources, dest = [a for a in args if not a.startswith("--")]
        for src in sources:
            assert (ROOT / src).exists(), f"COPY {src}: not in the build context (the repo root)"
    # the whole repo is copied into the WORKDIR and pip-installed from there
    assert any(srcs[-2:-1] == ["."] and PurePosixPath(srcs[-1]) == PurePosixPath(dockerfile_workdir())
               for srcs in ([a for a in c if not a.startswith("--")] for c in copies)), copies
    installs = [ln for ln in lines if ln.upper().startswith("RUN ") and "pip install" in ln]
    project = [ln for ln in installs if re.search(r"\s\.(\s|$)", ln)]
    assert project, f"no `pip install ... .` among {installs}"
    assert constraint_files()
    for c in constraint_files():  # every constraints file pip is given is in the repo and was copied
        assert (ROOT / c).is_file() and any(c in srcs for srcs in copies), c


def test_dockerfile_python_snippets_and_commands_name_real_code():
    """`python -c` snippets in the Dockerfile and cluster.yaml import what exists; the
    `farm` console script the image runs is declared and resolves to a callable."""
    texts = [(DEPLOY / "Dockerfile").read_text(), (DEPLOY / "cluster.yaml").read_text()]
    snippets = [s for t in texts for s in re.findall(r'python -c "([^"]*)"', t)]
    assert snippets
    for snippet in snippets:
        tree = ast.parse(snippet)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] in project_packages():
                        importlib.import_module(alias.name)
            elif isinstance(node, ast.ImportFrom) and node.module.split(".")[0] in project_packages():
                module = importlib.import_module(node.module)
                for alias in node.names:
                    assert hasattr(module, alias.name), f"{node.module} has no {alias.name}"
    if any(re.search(r"(^|\s)farm\s", ln) for ln in dockerfile_lines() if ln.upper().startswith("RUN ")):
        target = pyproject()["project"]["scripts"]["farm"]
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func))


def test_dockerfile_leaves_the_start_command_to_kuberay():
    for ln in dockerfile_lines():
        assert not ln.upper().startswith(("CMD ", "CMD[", "ENTRYPOINT")), f"{ln}: KubeRay supplies `ray start`"


def test_dockerignore_keeps_what_the_image_needs_and_drops_the_venv():
    build = docker_build()
    ignore = ROOT / (build["file"] + ".dockerignore")  # BuildKit reads <Dockerfile>.dockerignore
    assert ignore.is_file(), f"{ignore} (BuildKit's per-Dockerfile ignore file) is missing"
    rules = [ln.strip() for ln in ignore.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert rules[0] == "*", "allowlist expected: exclude everything first"
    kept = {r[1:].rstrip("/") for r in rules if r.startswith("!")}
    meta = pyproject()["project"]
    needed = {"pyproject.toml", meta["readme"]} | project_packages()
    needed |= set(constraint_files())
    needed |= {PurePosixPath(c).parts[0] for _, argv in farm_commands() for c in argv if c.startswith("configs/")}
    assert needed <= kept, f"missing from the build context: {needed - kept}"
    assert not {".venv", ".git", "results"} & kept


# ----- KubeRay ---------------------------------------------------------------------------------
def test_manifests_parse_and_have_what_kuberay_needs():
    docs = manifests()
    assert {d.get("kind") for d in docs.values()} >= {"RayCluster", "RayJob", "PersistentVolumeClaim"}
    for name, doc in docs.items():
        assert {"apiVersion", "kind", "metadata", "spec"} <= set(doc), name
        assert doc["metadata"].get("name"), name
        if doc["kind"] == "PersistentVolumeClaim":
            assert doc["apiVersion"] == "v1"
            assert doc["spec"]["accessModes"]
            assert quantity(doc["spec"]["resources"]["requests"]["storage"]) > 0
            continue
        assert doc["apiVersion"].startswith("ray.io/"), name
        if doc["kind"] == "RayJob":
            assert doc["spec"]["entrypoint"] and "rayClusterSpec" in doc["spec"], name
    for fname, spec in ray_cluster_specs():
        assert {"rayVersion", "headGroupSpec", "workerGroupSpecs"} <= set(spec), fname
        for gname, group in groups(spec):
            assert isinstance(group.get("rayStartParams"), dict), (fname, gname)
            pod = group["template"]["spec"]
            names = [c["name"] for c in pod.get("initContainers", []) + pod["containers"]]
            assert len(names) == len(set(names)), (fname, gname, names)
            volumes = {v["name"] for v in pod.get("volumes", [])}
            for c in pod["containers"]:
                assert c.get("image"), (fname, gname, c["name"])
                for m in c.get("volumeMounts", []):
                    assert m["name"] in volumes, f"{fname} {gname}: mount of undefined volume {m['name']}"


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_ray_version_is_the_images(fname, spec):
    assert spec["rayVersion"] == dockerfile_from()[0]


def test_rayjob_cluster_is_the_raycluster():
    (_, cluster), = of_kind("RayCluster")
    (_, job), = of_kind("RayJob")
    assert job["spec"]["rayClusterSpec"] == cluster["spec"], "rayjob.yaml's rayClusterSpec drifted from raycluster.yaml"


def test_images_are_the_one_the_readme_builds():
    """Every container (KubeRay, `ray up`) runs the image deploy/README.md's `docker build`
    makes, from the Dockerfile in the repo, tagged with the project's version."""
    build = docker_build()
    assert (ROOT / build["file"]).is_file() and (ROOT / build["context"]).resolve() == ROOT
    name, version = build["tag"].rsplit(":", 1)
    assert version == pyproject()["project"]["version"]
    images = {load(DEPLOY / "cluster.yaml")["docker"]["image"]}
    for _, spec in ray_cluster_specs():
        for _, group in groups(spec):
            pod = group["template"]["spec"]
            images |= {c.get("image") for c in pod.get("initContainers", []) + pod["containers"]}
    assert images == {build["tag"]}


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
def test_ray_start_params_are_ray_start_options_and_ports_are_exposed(fname, gname, group):
    """KubeRay turns rayStartParams into `ray start --key=value`: each must be an option of
    Ray's `ray start`, given as a string; the ports Ray then listens on are declared."""
    params = group["rayStartParams"]
    assert all(isinstance(v, str) for v in params.values()), "KubeRay wants string values"
    argv = ["ray", "start"] + (["--head"] if gname == "head" else []) + [f"--{k}={v}" for k, v in params.items()]
    _, opts = ray_cli(argv)
    ports = {p["containerPort"] for p in ray_container(group).get("ports", [])}
    assert opts["metrics_export_port"] is not None, "a fixed metrics port, so Prometheus can scrape it"
    assert opts["metrics_export_port"] in ports
    if gname == "head":
        import ray._private.ray_constants as rc

        assert opts["dashboard_host"] == "0.0.0.0", "the dashboard / job API must be reachable from the service"
        head_ports = {int(opts["port"] or rc.DEFAULT_PORT), opts["dashboard_port"],
                      opts["ray_client_server_port"] or 10001}  # ray start's client default (ray/scripts/scripts.py)
        assert head_ports <= ports, f"head listens on {head_ports}, declares {ports}"


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_worker_group_scaling_bounds(fname, spec):
    assert spec["workerGroupSpecs"], "no worker group"
    for g in spec["workerGroupSpecs"]:
        assert g["groupName"]
        assert 0 <= g["minReplicas"] <= g["replicas"] <= g["maxReplicas"]


@pytest.mark.parametrize("fname,spec", ray_cluster_specs(), ids=lambda x: x if isinstance(x, str) else None)
def test_head_keeps_results_on_the_results_volume(fname, spec):
    """Every `farm ... --out` the deploy files run writes under a head mount backed by the
    results PVC, which the image's user can write to (fsGroup = the Dockerfile's gid)."""
    mounts = head_results_mounts(spec)
    (_, pvc), = of_kind("PersistentVolumeClaim")
    outs = [args.out for _, argv in farm_commands() if (args := farm_cli(argv)).command == "sweep" and args.out]
    assert outs
    for out in outs:
        roots = [m for m in mounts if under(out, m)]
        assert roots, f"--out {out} is not on a volume of the head: lost with the pod"
        claim = mounts[roots[0]].get("persistentVolumeClaim", {}).get("claimName")
        assert claim == pvc["metadata"]["name"], f"--out {out} is on {mounts[roots[0]]}, not the results PVC"
    chowns = re.findall(r"chown\s+\d+:(\d+)", (DEPLOY / "Dockerfile").read_text())
    assert chowns
    assert spec["headGroupSpec"]["template"]["spec"].get("securityContext", {}).get("fsGroup") == int(chowns[0])


def test_rayjob_runs_a_real_farm_command_with_the_installed_package():
    (_, job), = of_kind("RayJob")
    spec = job["spec"]
    assert spec["submissionMode"] in {"K8sJobMode", "HTTPMode", "InteractiveMode", "SidecarMode"}  # KubeRay's enum
    assert isinstance(spec["shutdownAfterJobFinishes"], bool)
    assert isinstance(spec["ttlSecondsAfterFinished"], int) and spec["ttlSecondsAfterFinished"] >= 0
    args = farm_cli(shlex.split(spec["entrypoint"]))
    assert args.command == "sweep"
    runtime_env = yaml.safe_load(spec["runtimeEnvYAML"])
    # relative config paths resolve against the job's working dir: the image's WORKDIR
    assert PurePosixPath(runtime_env["working_dir"]) == PurePosixPath(dockerfile_workdir())
    # the installed, precompiled packages run, not an uploaded copy of their sources
    assert {f"{p}/" for p in project_packages()} <= set(runtime_env["excludes"])


def test_documented_farm_commands_parse_and_their_configs_load():
    commands = farm_commands()
    assert {where for where, _ in commands} >= {"README.md", "rayjob.yaml:entrypoint"}
    for _, argv in commands:
        farm_cli(argv)


def test_documented_ray_commands_parse_with_rays_cli():
    """Every `ray ...` line (README blocks, comments, cluster.yaml's start commands) is a real
    Ray subcommand with real options; `ray job submit` runtime envs are JSON that keeps the
    project's packages out of the upload; workers join the head's port."""
    commands = [(w, a) for w, a in documented_commands() if a[0] == "ray"]
    assert commands
    for where, argv in commands:
        path, params = ray_cli(argv)
        if path == ["ray", "job", "submit"] and params.get("runtime_env_json"):
            env = json.loads(params["runtime_env_json"])
            assert {f"{p}/" for p in project_packages()} <= set(env.get("excludes", [])), (where, env)
    cluster = load(DEPLOY / "cluster.yaml")
    head = [ray_cli(shlex.split(c))[1] for c in cluster["head_start_ray_commands"] if c.startswith("ray start")]
    workers = [ray_cli(shlex.split(c))[1] for c in cluster["worker_start_ray_commands"] if c.startswith("ray start")]
    assert len(head) == 1 and head[0]["head"] and workers
    for w in workers:
        assert not w["head"] and w["address"].rsplit(":", 1)[1] == str(head[0]["port"])


# ----- ray up ----------------------------------------------------------------------------------
def test_cluster_yaml_has_what_ray_up_needs():
    c = load(DEPLOY / "cluster.yaml")
    assert c["max_workers"] <= len(c["provider"]["worker_ips"])
    for local in c["file_mounts"].values():
        assert (ROOT / local).exists(), f"file mount source {local} (relative to the repo root)"
    # sweeps write under /data (see the README's commands): a docker volume, so results outlive `ray down`
    volumes = [o.split("=", 1)[1].split(":")[1] for o in c["docker"]["run_options"] if o.startswith("--volume=")]
    outs = [a.out for _, argv in farm_commands() if (a := farm_cli(argv)).command == "sweep" and a.out]
    for out in outs:
        assert any(under(out, v) for v in volumes), f"--out {out} is not on a docker volume of cluster.yaml"


def test_cluster_yaml_passes_rays_own_schema():
    from ray.autoscaler._private.util import prepare_config, validate_config

    validate_config(prepare_config(copy.deepcopy(load(DEPLOY / "cluster.yaml"))))


# ----- paths -----------------------------------------------------------------------------------
_REPO_PATH = re.compile(r"(?:(?<![\w.~/-])|(?<=\$PWD/))"
                        r"(?:(?:deploy|dashboards|configs|farm|workers|tests|benchmarks)/[\w./-]*\w)")


def test_repo_paths_named_in_deploy_exist():
    """Every repo path deploy/ and dashboards/README.md name (configs, manifests, the
    Dockerfile, code) is in the repo."""
    texts = [p.read_text() for p in DEPLOY.rglob("*") if p.is_file()]
    texts.append((ROOT / "dashboards" / "README.md").read_text())
    named = {m for t in texts for m in _REPO_PATH.findall(t)}
    assert any(n.startswith("configs/") for n in named), "deploy/ names no config"
    missing = sorted(n for n in named if not (ROOT / n).exists())
    assert not missing, f"named in deploy/ but not in the repo: {missing}"
