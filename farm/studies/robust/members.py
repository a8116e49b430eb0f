"""The members of the two populations of the meta-game: allocators and intruder policies, named
as the registries name them, and made from those names."""

from __future__ import annotations

import json
from pathlib import Path
from dataclasses import dataclass, field

from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

__all__ = ["check_member", "check_run", "relative_run", "MEASURES", "Member", "member_of", "against",
           "mixture_options", "play_pair"]

SIDES = ("allocators", "intruders")
MEASURES = ("eliminated", "breached", "return")  # a pair's measures, kept per episode


@dataclass(frozen=True)
class Member:
    """One pure strategy of the meta-game: side (allocators or intruders), name (a name of that
    side's registry) and options (its options, e.g. a learned member's `run` folder); label: how
    tables show it."""

    side: str
    name: str
    options: dict = field(default_factory=dict)
    label: str = ""

    def key(self, root=None) -> dict:
        """What identifies the member in a payoff's key: side, name and options (a `run` under root
        relative to it: the key of a folder that moved or was copied stays the same)."""
        return {"side": self.side, "name": self.name, "options": relative_run(self.options, root)}

    def shown(self) -> str:
        """The member's label, else its name (with its options when it has any)."""
        if self.label:
            return self.label
        return self.name if not self.options else f"{self.name} {json.dumps(self.options, sort_keys=True)}"

    def spec(self) -> dict:
        """The member as a mixture names it: {policy|intruders: name, options: {...}}."""
        return {("policy" if self.side == "allocators" else "intruders"): self.name, "options": dict(self.options)}

    def to_dict(self, root=None) -> dict:
        """Plain values (the loop's saved state; a `run` under root relative to it)."""
        return {"side": self.side, "name": self.name, "options": relative_run(self.options, root), "label": self.label}


def relative_run(options: dict, root) -> dict:
    """options with a `run` folder under root written relative to it (options itself otherwise)."""
    run = options.get("run")
    if root is None or not isinstance(run, str) or not Path(run).is_absolute():
        return options
    try:
        return {**options, "run": Path(run).resolve().relative_to(Path(root).resolve()).as_posix()}
    except ValueError:  # a run elsewhere (an exploit's learned.storage, a run given by path): as given
        return options


def member_of(side: str, value, where: str, root=None) -> Member:
    """A member from a config's or a saved state's value: a name, or {name, options, label}; a
    relative `run` is a folder under root (a saved state's folder). ConfigError (one line naming
    where) for anything else or an unknown name."""
    from farm.alloc.allocators import allocator_entry
    from farm.alloc.intruders import intruder_entry

    if isinstance(value, str):
        value = {"name": value}
    if not isinstance(value, dict) or not isinstance(value.get("name"), str) \
            or not set(value) <= {"name", "options", "label", "side"} or not isinstance(value.get("options", {}), dict):
        raise ConfigError(f"{where}: a member is a name or {{name: NAME, options: {{...}}}}, got {value!r}",
                          field=where)
    (allocator_entry if side == "allocators" else intruder_entry)(value["name"], where.split("[")[0])
    options = dict(value.get("options", {}))
    if root is not None and isinstance(options.get("run"), str) and not Path(options["run"]).is_absolute():
        options["run"] = str(Path(root) / options["run"])
    return Member(side, value["name"], options, value.get("label", ""))


def check_member(member: Member, config: AllocConfig, field: str) -> None:
    """ConfigError (one line naming field) for a member its side would refuse on config's map,
    checked before any work: an option its maker does not take, a value a baseline's or a
    planner's own checks refuse (the registry's check_options), a mixture's members and weights
    (each member checked so), a learned member's run folder (a trained model of this side)."""
    from farm.alloc.game.registry import ALLOCATORS, INTRUDERS
    from farm.core.mixture import mixture_members

    registry = ALLOCATORS if member.side == "allocators" else INTRUDERS
    entry = registry.entry(member.name, field)
    unknown = sorted(set(member.options) - set(entry.options()))
    if unknown:
        raise ConfigError(f"{field}: {member.name} has no option {unknown[0]!r} (options: "
                          f"{', '.join(entry.options()) or 'none'})", field=field)
    if entry.kind == "mixture":
        key = "policy" if member.side == "allocators" else "intruders"
        parsed, _ = mixture_members(field, member.options.get("members"), member.options.get("weights"),
                                    member.options.get("draw", "episode"), key)
        for k, (name, options) in enumerate(parsed):
            check_member(Member(member.side, name, options), config, f"{field}.members[{k}]")
    elif entry.kind == "learned":
        check_run(member.options.get("run"), member.side, field)
    else:
        registry.check_options(member.name, member.options, config, field)


def check_run(run, side: str, field: str) -> None:
    """ConfigError (one line naming field) unless run is a folder holding a trained model
    (model.zip, a zip file) of a training of side (its config.yaml's `side`)."""
    import zipfile

    import yaml

    if not isinstance(run, str) or not run:
        raise ConfigError(f"{field}: a learned member needs its run folder (options: {{run: PATH}})", field=field)
    model = Path(run) / "model.zip"
    if not model.is_file() or not zipfile.is_zipfile(model):
        raise ConfigError(f"{field}: {run} holds no trained model (model.zip); train it with farm train",
                          field=field)
    try:
        values = yaml.safe_load((Path(run) / "config.yaml").read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        values = None
    trained = values.get("side", "defenders") if isinstance(values, dict) else None
    wanted = "defenders" if side == "allocators" else "intruders"
    if trained != wanted:
        raise ConfigError(f"{field}: {run} is not a training of the {wanted} (its config.yaml says side: "
                          f"{trained})", field=field)

def against(config: AllocConfig, intruders: Member) -> AllocConfig:
    """The env settings config with the intruder member as its intruders."""
    return AllocConfig(**{**config.model_dump(), "intruders": intruders.name, "intruder_options": intruders.options})


def mixture_options(members: list[Member], weights) -> dict:
    """The options of a mixture (allocator or intruder) playing members with weights, drawn per episode."""
    return {"members": [m.spec() for m in members], "weights": [float(w) for w in weights], "draw": "episode"}


def play_pair(config: AllocConfig, allocator: Member, intruders: Member, client, episodes: int, seed: int) -> dict:
    """The allocator against the intruders on episodes seeded seed .. seed + episodes - 1:
    {measure: list of floats, one an episode} (farm.alloc.evaluation.rollout.play)."""
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.rollout import play

    env = against(config, intruders)
    played = play(env, make_allocator(allocator.name, env, client, **allocator.options), client, episodes, seed)
    return {m: [e.summary[m] for e in played] for m in MEASURES}
