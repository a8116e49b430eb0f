"""The documentation site: `mkdocs build --strict` passes (no broken link, reference or nav
entry), every page renders in headless Chromium with its images loaded and no console error,
and the config reference names every field of every config model."""

from __future__ import annotations

import dataclasses
import functools
import http.server
import importlib
import os
import pkgutil
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-quic"]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=300, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def served(site):
    handler = functools.partial(_QuietHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.mark.slow
def test_the_site_has_every_page_of_the_nav(site):
    pages = {p.relative_to(site).as_posix() for p in site.rglob("*.html")}
    for page in ["index.html", "getting-started.html", "model.html", "reference/cli.html",
                 "reference/configs/train.html", "reference/api/workers.html", "changelog.html", "deploy.html",
                 "benchmarks.html", "results.html", "tutorials/add-allocator.html"]:
        assert page in pages
    api = (site / "reference/api/workers.html").read_text()
    assert "simulate_games" in api and "capture_times" in api  # the docstrings are rendered
    cli = (site / "reference/cli.html").read_text()
    assert all(f"farm {c}" in cli for c in ("game", "sweep", "train", "eval", "experiments"))


@pytest.mark.slow
def test_every_page_renders_in_chromium_with_its_images_and_no_console_error(site, served):
    if CHROMIUM is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing on CI: `make browser` should have installed it")
        pytest.skip("chromium is not installed (make browser installs it)")
    from playwright.sync_api import sync_playwright

    pages = sorted(p.relative_to(site).as_posix() for p in site.rglob("*.html"))
    assert len(pages) >= 30
    problems = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        try:
            page = browser.new_page()
            errors: list[str] = []
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            # A file the site lacks is a 404, which Chromium logs as a console error. A request
            # ERR_ABORTED is the browser's own cancelling: the next page's navigation cancels a
            # request the last page left in flight (its search index, on a loaded machine).
            page.on("requestfailed", lambda r: None if r.failure == "net::ERR_ABORTED"
                    else errors.append(f"request failed: {r.url} ({r.failure})"))
            for name in pages:
                errors.clear()
                response = page.goto(f"{served}/{name}", wait_until="networkidle")
                state = page.evaluate("""() => {
                    const imgs = [...document.images];
                    return {text: (document.querySelector('article') || document.body).innerText.length,
                            images: imgs.length,
                            broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src)};
                }""")
                if (response is None or response.status != 200 or (state["text"] < 100 and name != "404.html")
                        or state["broken"] or errors):
                    problems.append((name, response and response.status, state, list(errors)))
        finally:
            browser.close()
    assert not problems, problems[:5]


def _config_models() -> list[type]:
    """Every config model of the project, found independently of the hook's list: each public
    subclass of farm.core.config.Strict, and the game settings' dataclasses."""
    import farm
    from farm.core.config import Strict
    from workers import Case, InitialLaw

    for module in pkgutil.walk_packages(farm.__path__, "farm."):
        importlib.import_module(module.name)

    def subclasses(cls):
        for sub in cls.__subclasses__():
            yield sub
            yield from subclasses(sub)

    return [m for m in set(subclasses(Strict)) if not m.__name__.startswith("_") and m.model_fields] + [Case,
                                                                                                        InitialLaw]


@pytest.mark.slow
def test_the_config_reference_names_every_field_of_every_config_model(site):
    text = {p.stem: p.read_text() for p in (site / "reference" / "configs").glob("*.html")}
    models = _config_models()
    assert len(models) >= 15
    missing = []
    for model in models:
        fields = ([f.name for f in dataclasses.fields(model)] if dataclasses.is_dataclass(model)
                  else list(model.model_fields))
        anchor = f'id="{model.__name__.lower()}"'
        homes = [html for html in text.values() if anchor in html]
        if len(homes) != 1:
            missing.append((model.__name__, "section", len(homes)))
            continue
        section = homes[0].split(anchor, 1)[1]
        section = re.split(r"<h2 id=", section, maxsplit=1)[0]
        missing += [(model.__name__, f) for f in fields if f"<code>{f}</code>" not in section]
    assert not missing, missing


@pytest.mark.slow
def test_every_config_field_has_a_description_in_the_reference(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "tools"))  # tools/mkdocs_hooks.py, as mkdocs loads it
    hooks = importlib.import_module("mkdocs_hooks")
    seen, missing = set(), []
    todo = [model for _, _, _, roots, _ in hooks.config_pages() for model in roots]
    while todo:
        model = todo.pop()
        if model in seen:
            continue
        seen.add(model)
        for name, annotation, *_, description in hooks._field_rows(model):
            if not description.strip():
                missing.append(f"{model.__module__}.{model.__name__}.{name}")
            todo += hooks._models_in(annotation)  # nested models (sections) too
    assert len(seen) >= 15
    assert not missing, f"{len(missing)} config field(s) without a description: {', '.join(missing)}"


def test_the_readme_is_short_and_keeps_its_two_commands():
    """README.md stays a front page: at most 220 lines, its two set-up commands, and every
    relative link pointing at a file or folder of the repository (web links and #anchors aside)."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 220
    assert "make demo" in text and "make test" in text
    targets = [t for t in re.findall(r"!?\[[^\]]*\]\(([^)\s]+)\)", text) if not re.match(r"[a-z][a-z0-9+.-]*:|#", t)]
    assert targets
    missing = [t for t in targets if not (ROOT / t.split("#", 1)[0]).exists()]
    assert not missing, missing
