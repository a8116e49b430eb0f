"""MkDocs hooks (mkdocs.yml `hooks:`): the pages that are generated from the code, so that
what they say is written once, where it is defined.

- reference/configs/*.md: every field of every config model (the pydantic models of the
  config files, and workers.Case's game settings), with its type, default, bounds and the
  comment beside its definition; each page ends with a real config file of that kind.
- reference/cli.md: `farm --help` and every subcommand's help, from farm.cli.build_parser.
- changelog.md, deploy.md, dashboards.md, benchmarks.md: the repository's CHANGELOG.md and
  the READMEs of deploy/, dashboards/ and benchmarks/, their links into the repository
  turned into plain paths (the site holds only docs/).
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import io
import os
import re
import tokenize
import typing
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]

# Pages copied from elsewhere in the repository: site path -> repository file.
INCLUDED = {
    "changelog.md": "CHANGELOG.md",
    "deploy.md": "deploy/README.md",
    "dashboards.md": "dashboards/README.md",
    "benchmarks.md": "benchmarks/README.md",
}


def config_pages():
    """The config reference's pages: (page name, title, what it is, root models, example file).
    Nested models are documented on the first page that reaches them."""
    from farm.alloc.game.config import AllocConfig
    from farm.alloc.training.config import TrainConfig
    from farm.games.sweep.config import SweepConfig
    from farm.service.table import TableConfig
    from farm.studies.experiments.config import ExperimentConfig
    from farm.studies.exploit.config import ExploitConfig
    from farm.studies.robust.config import RobustConfig
    from farm.studies.suite.config import SuiteConfig
    from workers import Case, InitialLaw

    return [
        ("game", "Game settings", "A pursuit-evasion game's parameters (`workers.Case`): the settings a sweep's "
         "`base` and `vary`, a table's `settings`, an env's game fields and `farm game`'s flags name.",
         [Case, InitialLaw], None),
        ("sweep", "Sweep configs", "`farm sweep CONFIG`: a parametric Monte Carlo sweep.", [SweepConfig],
         "configs/smoke.yaml"),
        ("table", "Table configs", "`farm table CONFIG`: fill the capture-time store.", [TableConfig],
         "configs/table_small.yaml"),
        ("env", "Allocation env settings", "The allocation MDP's settings: `gym.make('farm/SwarmAllocation-v0', "
         "**settings)`, a training config's `env:` and a scenario's map.", [AllocConfig], None),
        ("train", "Training configs", "`farm train CONFIG`: one learner trained into a run folder.", [TrainConfig],
         "configs/train/demo_3x3.yaml"),
        ("suite", "Suite configs", "`farm suite CONFIG`: every policy on every scenario, one leaderboard.",
         [SuiteConfig], "configs/suite_demo.yaml"),
        ("experiments", "Experiment configs", "`farm experiments CONFIG`: a grid of training settings over seeds, "
         "as Ray Tune trials.", [ExperimentConfig], "configs/experiments/smoke.yaml"),
        ("exploit", "Exploit configs", "`farm exploit CONFIG`: allocators against adapting intruders, their worst "
         "case and its drop.", [ExploitConfig], "configs/exploit/smoke.yaml"),
        ("robust", "Robust configs", "`farm robust CONFIG`: policy-space response oracles for the allocation game.",
         [RobustConfig], "configs/robust/smoke.yaml"),
    ]


def _is_model(t) -> bool:
    from pydantic import BaseModel

    return isinstance(t, type) and (issubclass(t, BaseModel) or dataclasses.is_dataclass(t))


def _models_in(annotation) -> list[type]:
    if _is_model(annotation):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models_in(arg)]


def _type_name(annotation) -> str:
    if annotation is type(None):
        return "None"
    if isinstance(annotation, type) and not typing.get_args(annotation):
        return annotation.__name__
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " | ".join(_type_name(a) for a in args)
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join('...' if a is Ellipsis else _type_name(a) for a in args)}]"
    return str(annotation).replace("typing.", "")


def _comments(cls) -> dict[str, str]:
    """The comment beside each field's definition in cls's body, or the comment lines just above it."""
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    comment_at = {tok.start[0]: tok.string.lstrip("#").strip()
                  for tok in tokenize.generate_tokens(io.StringIO(source).readline) if tok.type == tokenize.COMMENT}
    out = {}
    for number, line in enumerate(lines, start=1):
        m = re.match(r"    (\w+)\s*:", line)
        if not m:
            continue
        if number in comment_at:
            out[m.group(1)] = comment_at[number]
            continue
        above, j = [], number - 1
        while j >= 1 and re.match(r"    #", lines[j - 1]) and j in comment_at:
            above.insert(0, comment_at[j])
            j -= 1
        if above:
            out[m.group(1)] = " ".join(above)
    return out


def _field_rows(model) -> list[tuple[str, object, str, str, str]]:
    """(name, annotation, default, bounds, description) of each of model's fields."""
    comments = {}
    for cls in reversed(model.__mro__):
        comments.update(_comments(cls))
    rows = []
    if dataclasses.is_dataclass(model):
        hints = typing.get_type_hints(model)
        for f in dataclasses.fields(model):
            if f.default is not dataclasses.MISSING:
                default = repr(f.default)
            elif f.default_factory is not dataclasses.MISSING:
                value = f.default_factory()
                default = f"{type(value).__name__}()" if _is_model(type(value)) else repr(value)
            else:
                default = "required"
            rows.append((f.name, hints[f.name], default, "", comments.get(f.name, "")))
        return rows
    from pydantic_core import PydanticUndefined

    for name, info in model.model_fields.items():
        if info.is_required():
            default = "required"
        elif info.default is PydanticUndefined:
            default = repr(info.default_factory())
        elif _is_model(type(info.default)):
            default = "its defaults"
        else:
            default = repr(info.default)
        bounds = []
        for meta in info.metadata:
            for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<"), ("min_length", "length >="),
                               ("max_length", "length <="), ("pattern", "matches")):
                value = getattr(meta, attr, None)
                if value is not None:
                    bounds.append(f"{sign} `{value}`" if attr == "pattern" else f"{sign} {value}")
        description = info.description or comments.get(name, "") or _game_setting(model, name)
        rows.append((name, info.annotation, default, ", ".join(bounds), description))
    return rows


def _game_setting(model, name: str) -> str:
    """The description of a game setting a model takes over from workers.Case (AllocConfig's
    optional settings, made with create_model, have no line of their own): Case's comment."""
    from farm.core.config import SETTING_FIELDS
    from workers import Case

    if name not in SETTING_FIELDS or model is Case:
        return ""
    own = _comments(Case).get(name, "")
    return f"as workers.Case's `{name}`: {own}; None: the engagement's value, else Case's default" if own else ""


def _anchor(model) -> str:
    return model.__name__.lower().lstrip("_")


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def config_page(title: str, about: str, roots: list[type], example: str | None, homes: dict) -> str:
    """The markdown of one config reference page: each model reached from roots (not documented
    on an earlier page) with a table of its fields; `homes` maps a model to its page."""
    page = homes[roots[0]]
    models, todo = [], list(roots)
    while todo:
        model = todo.pop(0)
        if model in models:
            continue
        models.append(model)
        for _, annotation, *_ in _field_rows(model):
            for nested in _models_in(annotation):
                homes.setdefault(nested, page)
                if homes[nested] == page and nested not in models:
                    todo.append(nested)
    out = [f"# {title}", "", about, "",
           "Generated from the models' definitions by `tools/mkdocs_hooks.py`: every field, its type, "
           "default and bounds, and the comment beside it in the code. A key that is not a field is refused.", ""]
    for model in models:
        doc = inspect.cleandoc(model.__doc__ or "")
        out += [f"## {model.__name__} {{#{_anchor(model)}}}", "", f"`{model.__module__}.{model.__name__}`", "",
                doc, "", "| field | type | default | bounds | description |", "|---|---|---|---|---|"]
        for name, annotation, default, bounds, description in _field_rows(model):
            kind = _cell(_type_name(annotation))
            links = [f"[{m.__name__}]({'' if homes[m] == page else homes[m] + '.md'}#{_anchor(m)})"
                     for m in _models_in(annotation) if m in homes]
            shown = f"`{kind}`" + (f" ({', '.join(links)})" if links else "")
            out.append(f"| `{name}` | {shown} | `{_cell(default)}` | {_cell(bounds)} | {_cell(description)} |")
        out.append("")
    if example:
        text = (ROOT / example).read_text()
        out += ["## An example", "", f"`{example}`:", "", "```yaml", text.rstrip(), "```", ""]
    return "\n".join(out)


def config_reference() -> dict[str, str]:
    """Every config reference page: {'reference/configs/NAME.md': markdown}, and its index."""
    pages = config_pages()
    homes = {}
    for name, _, _, roots, _ in pages:
        for model in roots:
            homes.setdefault(model, name)
    out = {}
    index = ["# Config reference", "", "Each config file is one model; a key that is not one of its fields is "
             "refused with one line naming it.", "", "| page | what |", "|---|---|"]
    for name, title, about, roots, example in pages:
        out[f"reference/configs/{name}.md"] = config_page(title, about, roots, example, homes)
        index.append(f"| [{title}]({name}.md) | {_cell(about)} |")
    out["reference/configs/index.md"] = "\n".join(index) + "\n"
    return out


def cli_reference() -> str:
    """The CLI page: `farm --help`, then each subcommand's `--help`, as argparse prints them."""
    from farm.cli import build_parser

    def help_of(*argv) -> str:
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer), contextlib.suppress(SystemExit):
            build_parser().parse_args([*argv, "--help"])
        return buffer.getvalue().rstrip()

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        top = help_of()
        commands = re.search(r"\{([a-z,-]+)\}", top).group(1).split(",")
        out = ["# The `farm` command line", "", "Generated from `farm.cli.build_parser` by `tools/mkdocs_hooks.py`. "
               "Every error is one line naming the flag; `--debug` (or `SWARM_FARM_DEBUG=1`) shows the traceback.", "",
               "```text", top, "```", ""]
        for command in commands:
            out += [f"## farm {command}", "", "```text", help_of(command), "```", ""]
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(out)


_LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")


def included_page(repo_file: str, site_page: str, known: set[str]) -> str:
    """A repository file's markdown for the site: a link to another page of the site kept (its
    path rewritten from the file's folder to the page's), a link into the repository shown as
    its path, web links kept."""
    source = ROOT / repo_file

    def rewrite(m):
        bang, text, target = m.groups()
        if re.match(r"[a-z]+:|#", target):
            return m.group(0)
        path, _, anchor = target.partition("#")
        resolved = os.path.normpath(source.parent.joinpath(path)).replace(os.sep, "/")
        relative = os.path.relpath(resolved, ROOT).replace(os.sep, "/")
        if relative.startswith("docs/") and relative[5:] in known:
            return f"{bang}[{text}]({os.path.relpath(relative[5:], os.path.dirname(site_page) or '.')}" \
                   f"{'#' + anchor if anchor else ''})"
        pages = {v: k for k, v in INCLUDED.items()}
        if relative in pages:
            return f"[{text}]({pages[relative]}{'#' + anchor if anchor else ''})"
        return f"{text} (`{relative}`)" if text.strip("`") != relative else f"`{relative}`"

    return _LINK.sub(rewrite, source.read_text())


def on_files(files, config):
    """Add the generated pages and the included repository files to the site's files."""
    known = {f.src_uri for f in files}
    generated = {**config_reference(), "reference/cli.md": cli_reference()}
    for page, repo_file in INCLUDED.items():
        if (ROOT / repo_file).exists():
            generated[page] = included_page(repo_file, page, known | set(generated))
    for uri, content in generated.items():
        if uri in known:
            files.remove(files.get_file_from_path(uri))
        files.append(File.generated(config, uri, content=content))
    return files
