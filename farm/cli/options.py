"""What the `farm` commands share: the parser whose errors are one line, the flags of a game's
settings and of a Ray cluster, the parsing of numbers, points and JSON files, a library error
named by its flag, and the one-line warnings and errors of `main`."""

from __future__ import annotations

import argparse
import json
import re
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from workers import GAME_FIELDS, SwarmFarmError
from workers.policies import EVADER_POLICIES, PURSUER_POLICIES

from farm.core.config import case_from
from farm.core.errors import CliError

# Flags of the game's settings: one per workers.Case field, default None (Case's default).
GAME_FLAG_HELP = {
    "pursuer_policy": f"one of {', '.join(sorted(PURSUER_POLICIES))}",
    "evader_policy": f"one of {', '.join(sorted(EVADER_POLICIES))}",
    "target": "target point of `target` evaders, 'x,y'",
    "arena": "JSON file with the arena's vertices [[x, y], ...] (default: [0,10]^2 square)",
    "exit_point": "'x,y': an evader within r_c of it escapes (engagement v2; default: no exit)",
    "law": "initial positions: boxes (the paper's start boxes) or uniform",
    "pursuer_speed": "pursuers' top speed",
    "evader_speed": "evaders' top speed",
}
GAME_FLAGS = tuple(name for name in GAME_FIELDS if name not in ("n_pursuers", "n_evaders", "tau"))
SPEED_FLAGS = ("pursuer_speed", "evader_speed")


class Parser(argparse.ArgumentParser):
    """The `farm` parser and its subcommands' parsers: a bad command line is a CliError of one
    line (`farm: error: <command>: <problem>`), without argparse's usage dump."""

    def error(self, message):
        """Raise CliError of message, after the subcommand's name for a subcommand's parser."""
        raise CliError(message if self.prog == "farm" else f"{self.prog.split()[-1]}: {message}")


@contextmanager
def flags(*names: str, **renamed: str):
    """Re-raise a library error about a field the command has a flag for as that flag's error:
    an error with field "out" becomes "--out: <its problem>". names: fields named as their
    flags; renamed: flag=field where the library's field is named otherwise. A dotted field
    (law.kind) maps through its first part (--law: kind: ...)."""
    to_flag = {**{n: n for n in names}, **{field: flag for flag, field in renamed.items()}}
    try:
        yield
    except SwarmFarmError as e:
        field = getattr(e, "field", None)
        name, _, sub = (field or "").partition(".")
        if name in to_flag:
            raise CliError(f"--{to_flag[name].replace('_', '-')}: {sub + ': ' if sub else ''}{e.problem}") from None
        raise


def refuse_contradictions(args, pairs) -> None:
    """CliError naming both flags when two flags that contradict each other (or one that the
    other makes ignored) are both given; a flag counts as given when it is not None."""
    for first, second in pairs:
        if getattr(args, first) is not None and getattr(args, second) is not None:
            raise CliError(f"--{first.replace('_', '-')} and --{second.replace('_', '-')}: give one or the other "
                           f"(with --{first.replace('_', '-')}, --{second.replace('_', '-')} would be ignored)")


def whole_numbers(text: str, field: str) -> list[int]:
    """The whole numbers >= 0 of comma-separated text; CliError naming field for an entry that is
    not one (0.5, nan, -1, a word) or an empty one."""
    entries = text.split(",")
    if not all(x.strip().isdigit() for x in entries):
        raise CliError(f"{field}: expected comma-separated whole numbers >= 0, got {text!r}")
    return [int(x) for x in entries]


def floats(text: str, field: str, n: int | None = None) -> list[float]:
    """The numbers of comma- (or semicolon-) separated text; CliError naming field for an empty
    entry, a word that is not a number, or other than n numbers when n is given."""
    entries = text.replace(";", ",").split(",")
    if text.strip() and any(not x.strip() for x in entries):
        raise CliError(f"{field}: an empty entry in {text!r}")
    try:
        values = [float(x) for x in entries if x.strip()]
    except ValueError:
        raise CliError(f"{field}: expected comma-separated numbers, got {text!r}") from None
    if n is not None and len(values) != n:
        raise CliError(f"{field}: expected {n} numbers, got {text!r}")
    return values


def points(text: str, field: str) -> np.ndarray:
    """The points 'x,y;x,y;...' of text, (n, 2) float64; CliError naming field otherwise."""
    v = floats(text, field)
    if len(v) == 0 or len(v) % 2:
        raise CliError(f"{field}: expected x,y pairs like '4,5;8,5', got {text!r}")
    return np.array(v).reshape(-1, 2)


def load_json(path: str, field: str):
    """The parsed JSON file at path; CliError naming field for a file missing, unreadable or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CliError(f"{field}: no such file {path!r}") from None
    except OSError as e:
        raise CliError(f"{field}: cannot read {path!r} ({e.strerror or type(e).__name__})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CliError(f"{field}: {path!r} is not valid JSON ({e.__class__.__name__})") from None


def add_game_options(p: argparse.ArgumentParser, names=GAME_FLAGS) -> None:
    """A flag for each of the game's settings names (--pursuer-policy, --dt, ...), default None."""
    from workers import Case

    defaults = {f: v.default for f, v in Case.__dataclass_fields__.items()}
    for name in names:
        default = defaults.get(name)
        shown = "the paper's boxes" if name == "law" else "none" if default is None else default
        p.add_argument("--" + name.replace("_", "-"), dest=name, default=None, metavar=name.upper(),
                       help=f"{GAME_FLAG_HELP.get(name, name.replace('_', ' '))} (default: {shown})")


def game_settings(args, names=GAME_FLAGS) -> dict:
    """The game flags given, as plain values for farm.core.config.case_from."""
    out = {}
    for name in names:
        text = getattr(args, name)
        if text is None:
            continue
        flag = "--" + name.replace("_", "-")
        if name in ("target", "exit_point"):
            out[name] = floats(text, flag, 2)
        elif name == "arena":
            out[name] = load_json(text, flag)
        elif name == "law":
            out[name] = {"kind": text}
        else:
            out[name] = text
    return out


def checked_case(fields: dict):
    """case_from(fields), its error naming the flag when the field came from one."""
    with flags(*GAME_FLAGS, "n_pursuers", "n_evaders"):
        return case_from(fields)


def add_cluster_options(p: argparse.ArgumentParser, workers_help: str) -> None:
    """--address, --workers and --quiet of a command that runs on Ray."""
    p.add_argument("--address", help="Ray cluster to join (default: $RAY_ADDRESS, else a local 2-CPU Ray)")
    p.add_argument("--workers", type=int, help=workers_help)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


_NEGATIVE = re.compile(r"^-\.?\d")


def join_negative_values(argv: list[str]) -> list[str]:
    """`--target -1,5` as `--target=-1,5`: argparse takes a value that starts with '-' for a
    flag unless it is a plain number, so coordinates like -1,5 would need the '='."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(str(token))
    return out


def refuse_empty_values(parser: argparse.ArgumentParser, args) -> None:
    """CliError naming the flag (or argument) given an empty value (`--animate ''`, `--out ''`):
    a flag given is never read as left out, nor an empty path as the current folder."""
    chosen = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen.append(action.choices[args.command])
    for p in chosen:
        for action in p._actions:
            value = getattr(args, action.dest, None)
            if isinstance(value, str) and not value.strip():
                if action.option_strings:
                    name = max(action.option_strings, key=len)
                    raise CliError(f"{name}: an empty value; give one, or leave {name} out")
                raise CliError(f"{action.dest}: an empty value")


_WARNED: set[str] = set()


def one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Show a warning as one line `farm: warning: ...`, each text once per command."""
    if str(message) not in _WARNED:
        _WARNED.add(str(message))
        print(f"farm: warning: {message}", file=sys.stderr)


def ray_errors() -> tuple:
    """Ray's exception base class, if Ray was imported (a command that used no Ray raised none)."""
    exceptions = sys.modules.get("ray.exceptions")
    return (exceptions.RayError,) if exceptions is not None else ()
