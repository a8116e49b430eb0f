"""The allocation MDP's settings (docs/model.md section 5), one typed model.

The MDP's own fields are declared here. The games behind each engagement are
workers.Case's settings (every Case field but the team sizes, which each cell's
densities set) and may be named here too, e.g. `evader_speed: 0.5` or
`law: {kind: uniform}`; they are not declared again: AllocConfig's game fields
are made from Case's, and a field left out takes its engagement's value, else
Case's default.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, create_model, model_serializer, model_validator

from farm.core.checks import is_positive
from farm.core.config import CASE_TYPES, SETTING_FIELDS, Strict, case_from
from farm.service.keys import GameSettings
from workers import Case
from workers.engine import case_defaults

CELL_SIDE = 10.0  # each cell is one PE arena, the square [0, 10]^2
EXIT = (0.0, 5.0)  # the intruders' exit: the middle of the cell's left (defenders') side

ENGAGEMENT_DEFAULTS = {
    "v1": {"pursuer_policy": "area_min", "evader_policy": "centroid", "tau": 5.0, "t_max": 10.0,
           "capture_time_norm": 10.0, "exit_point": None, "capture_score": "conditional"},
    "v2": {"pursuer_policy": "pure_pursuit", "evader_policy": "target", "exit_point": EXIT,
           "capture_score": "expected"},
}
_SERVICE = GameSettings()


def _positive(x) -> bool:
    """Whether x is a positive finite number (not a bool), or text that reads as one."""
    if isinstance(x, str):
        try:
            x = float(x)
        except ValueError:
            return False
    return isinstance(x, (int, float)) and is_positive(x)  # Python's numbers, as YAML gives them


class _AllocFields(Strict):
    grid_size: int = Field(3, ge=2, le=32)  # N: the map is an N x N grid of cells
    n_defenders: int = Field(100, ge=1, le=100_000)  # N_def: a cell's n_p = round(D_c * n_defenders)
    n_intruders: int = Field(50, ge=1, le=100_000)  # N_int: a cell's n_e = max(1, round(I_c * n_intruders))
    c_distribution: float = Field(1.0, ge=0, allow_inf_nan=False)  # reward weight of the intruder mass left, sum(I)
    c_capture: float = Field(0.0, ge=0, allow_inf_nan=False)  # reward weight of the step's capture score S_k
    breach_penalty: float = Field(1.0, ge=0, allow_inf_nan=False)  # reward weight of the mass breached this step (B_k)
    action_map: Literal["softmax", "shifted"] = "softmax"  # moves' shares: softmax(beta a), or shifted (a+1)/sum(a+1)
    softmax_beta: float = Field(5.0, gt=0, allow_inf_nan=False)  # beta of action_map softmax
    vertical_drift: float = Field(0.0, ge=0, le=0.5)  # intruder mass share a row sends to each neighbouring row a step
    max_steps: int = Field(12, ge=1, le=10_000)  # steps after which an episode is truncated
    epsilon: float = Field(1e-3, gt=0, lt=1)  # an episode terminates when the intruder mass falls below it
    engage_min_mass: float = Field(1e-6, ge=0)  # a cell engages only with more intruder mass than this
    team_sizes: Literal["exact", "lattice"] = "exact"  # exact: rounded; lattice: snapped to 1, 2, 3, 4, 6, 8, 12, ...
    engagement: Literal["v1", "v2"] = "v2"  # v2: the games tied to the MDP step; v1: area_min v centroid, 5 s window
    step_seconds: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: CELL_SIDE / evader_speed
    capture_time_norm: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: tau
    capture_score: Literal["expected", "conditional"] | None = None  # v2: expected, v1: conditional
    games: int = Field(_SERVICE.games, ge=2, le=100_000)  # games per case in the capture-time service
    seed: int = Field(_SERVICE.seed, ge=0)  # the service's seed of those games
    # The intruders as a player (docs/model.md section 8): their policy (farm.alloc.intruders' registry),
    # its options, and what they see when they route: the defenders after their move (follower) or the
    # state both sides choose from (simultaneous).
    intruders: str = "drift"
    intruder_options: dict[str, Any] = Field(default_factory=dict)  # the intruder policy's options (learned: run)
    information: Literal["follower", "simultaneous"] = "follower"  # follower: the intruders see D'; simultaneous: D


INTRUDER_FIELDS = ("intruders", "intruder_options", "information")  # written out only when not at their defaults


# workers.Case's settings, each optional: None means the engagement's value, else Case's default.
_GAME_FIELDS = {name: (CASE_TYPES[name] | None, None) for name in SETTING_FIELDS}


class AllocConfig(create_model("_AllocGame", __base__=_AllocFields, **_GAME_FIELDS)):
    """The allocation MDP's settings: its own fields and the engagement games' Case settings.

    The MDP's fields are _AllocFields' (above); the games' are every workers.Case setting
    but the team sizes, each None by default, which means the engagement's value
    (ENGAGEMENT_DEFAULTS, and under v2 the window tied to the step), else Case's default.

    Engagement model v2 (the default) ties the layers together: one MDP step lasts the
    time an intruder needs to cross a cell (step_seconds = cell side / the intruders'
    speed `evader_speed` = 10 s), the engagement window is that step (tau = step_seconds),
    the cell's games run no longer (t_max = tau) and are the paper's Table 1 setting,
    pure pursuit against intruders heading for the exit (0, 5) that escape through it,
    and the capture score is an expectation over all of a cell's games, normalised by the
    window (`capture_score: expected`, capture_time_norm = tau). Engagement v1 (`engagement: v1`),
    kept for comparison: area_min against centroid, tau 5 s, t_max 10 s, no exit,
    capture_time_norm 10 and the conditional score (`capture_score: conditional`: the mean
    capture time of the games that caught someone). A value that contradicts the
    engagement's coupling is one clear error.

    A bad or contradictory value raises pydantic's ValidationError naming the field.
    """

    @model_validator(mode="before")
    @classmethod
    def _engagement_defaults(cls, data):
        if not isinstance(data, dict):
            return data
        data = dict(data)
        if "intruder_speed" in data:  # a run folder's old field name intruder_speed
            data.setdefault("evader_speed", data.pop("intruder_speed"))
        if isinstance(data.get("law"), str):
            data["law"] = {"kind": data["law"]}
        engagement = data.get("engagement", "v2")
        if not isinstance(engagement, str) or engagement not in ENGAGEMENT_DEFAULTS:
            return data  # the field's own check names the problem
        for name, value in ENGAGEMENT_DEFAULTS[engagement].items():
            if data.get(name) is None and (name != "exit_point" or "exit_point" not in data):
                data[name] = value
        if engagement == "v2":  # step -> window -> games' length and the score's norm
            speed = data.get("evader_speed")
            # a bad speed is Case's to report
            speed = float(speed) if _positive(speed) else case_defaults(evader_speed=None)[0]
            if data.get("step_seconds") is None:
                data["step_seconds"] = CELL_SIDE / speed
            # a bad value is never copied on: its own field's check names it
            if data.get("tau") is None and _positive(data["step_seconds"]):
                data["tau"] = data["step_seconds"]
            for name in ("t_max", "capture_time_norm"):
                if data.get(name) is None and _positive(data.get("tau")):
                    data[name] = data["tau"]
        return data

    @model_validator(mode="after")
    def _coupled(self):
        from farm.alloc.game.registry import INTRUDERS

        entry = INTRUDERS.entry(self.intruders)  # an unknown policy: one line naming `intruders`
        unknown = sorted(set(self.intruder_options) - set(entry.options()))
        if unknown:  # an option the policy would not take (the drift law takes none)
            raise ValueError(f"intruder_options: {self.intruders} has no option {unknown[0]!r} "
                             f"(options: {', '.join(entry.options()) or 'none'})")
        case = self.game()  # Case's own checks of the game's settings
        if self.engagement == "v1":
            if self.step_seconds is not None:
                raise ValueError("step_seconds: only engagement v2 ties the step to a cell crossing; "
                                 "leave it out under v1")
        elif abs(case.tau - self.step_seconds) > 1e-9 * self.step_seconds:
            raise ValueError(f"tau: under engagement v2 the window is the step (step_seconds = "
                             f"{self.step_seconds:g} s), got {case.tau:g} (for the earlier model, set "
                             f"engagement: v1)")
        if case.t_max < case.tau - 1e-9:
            raise ValueError(f"t_max: the games ({case.t_max:g} s) must last the window tau ({case.tau:g} s)")
        if self.capture_score == "expected" and abs(self.capture_time_norm - case.tau) > 1e-9 * case.tau:
            raise ValueError(f"capture_time_norm: the expected capture score is normalised by the window tau "
                             f"({case.tau:g} s), got {self.capture_time_norm:g} (for another norm, set "
                             f"capture_score: conditional)")
        return self

    @model_serializer(mode="wrap")
    def _without_default_intruders(self, handler):
        """The settings as written (config.yaml, manifests): the intruder fields only when set otherwise."""
        data = handler(self)
        for name in INTRUDER_FIELDS:
            if name in data and getattr(self, name) == _AllocFields.model_fields[name].get_default(
                    call_default_factory=True):
                del data[name]
        return data

    def game(self) -> Case:
        """The engagement games' Case (team sizes 1 v 1; each engaged cell sets its own)."""
        given = {name: getattr(self, name) for name in SETTING_FIELDS if getattr(self, name) is not None}
        return case_from({"n_pursuers": 1, "n_evaders": 1, **given})

    def game_settings(self) -> GameSettings:
        """The capture-time service's settings of the engagements."""
        return GameSettings(self.game(), self.games, self.seed)

    def window_defaults(self) -> dict:
        """The engagement-dependent settings as resolved: step_seconds, tau, t_max, capture_time_norm."""
        return {k: getattr(self, k) for k in ("step_seconds", "tau", "t_max", "capture_time_norm")}
