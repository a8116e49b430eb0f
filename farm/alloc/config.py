"""The allocation MDP's settings (SPEC.md section 5), one typed model, every default here.

Engagement model v2 (the default) ties the layers together: one MDP step lasts the
time an intruder needs to cross a cell (step_seconds = cell side / intruder speed =
10 s), the engagement window is that step (tau = step_seconds), the cell's games run
no longer (t_max = tau) and are the paper's Table 1 setting, pure pursuit against
intruders heading for the exit (0, 5) that escape through it, and the capture score
is normalised by the window (capture_time_norm = tau). v1 (`engagement: v1`) is the
earlier model, for comparison: area_min against centroid, tau 5 s, t_max 10 s, no
exit, capture_time_norm 10. Fields left out take their engagement's value; a value
that contradicts the engagement's coupling is one clear error.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

CELL_SIDE = 10.0  # each cell is one PE arena, the square [0, 10]^2
EXIT = (0.0, 5.0)  # the intruders' exit: the middle of the cell's left (defenders') side

ENGAGEMENT_DEFAULTS = {
    "v1": {"pursuer_policy": "area_min", "evader_policy": "centroid", "tau": 5.0, "t_max": 10.0,
           "capture_time_norm": 10.0, "exit_point": None},
    "v2": {"pursuer_policy": "pure_pursuit", "evader_policy": "target", "exit_point": EXIT},
}


class AllocConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    grid_size: int = Field(3, ge=2, le=32)
    n_defenders: int = Field(100, ge=1, le=100_000)
    n_intruders: int = Field(50, ge=1, le=100_000)
    c_distribution: float = Field(1.0, ge=0, allow_inf_nan=False)
    c_capture: float = Field(0.0, ge=0, allow_inf_nan=False)
    breach_penalty: float = Field(1.0, ge=0, allow_inf_nan=False)
    action_map: Literal["softmax", "shifted"] = "softmax"
    softmax_beta: float = Field(5.0, gt=0, allow_inf_nan=False)
    vertical_drift: float = Field(0.0, ge=0, le=0.5)
    max_steps: int = Field(12, ge=1, le=10_000)
    epsilon: float = Field(1e-3, gt=0, lt=1)
    engage_min_mass: float = Field(1e-6, ge=0)
    team_sizes: Literal["exact", "lattice"] = "exact"
    engagement: Literal["v1", "v2"] = "v2"
    # The PE games behind each engagement (the capture-time service's settings); None: the
    # engagement's value (module doc).
    intruder_speed: float = Field(1.0, gt=0, allow_inf_nan=False)  # the evaders' speed in the cell's games
    step_seconds: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: CELL_SIDE / intruder_speed
    pursuer_policy: str | None = None
    evader_policy: str | None = None
    tau: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: step_seconds
    t_max: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: tau
    capture_time_norm: float | None = Field(None, gt=0, allow_inf_nan=False)  # v2: tau
    exit_point: tuple[float, float] | None = None  # v2: EXIT; v1: none
    law: Literal["boxes", "uniform"] = "boxes"  # boxes: the paper's start boxes (SPEC.md section 3)
    games: int = Field(64, ge=2, le=100_000)
    seed: int = Field(0, ge=0)

    @model_validator(mode="before")
    @classmethod
    def _engagement_defaults(cls, data):
        if not isinstance(data, dict):
            return data
        data = dict(data)
        engagement = data.get("engagement", "v2")
        if engagement not in ENGAGEMENT_DEFAULTS:
            return data  # the field's own check names the problem
        for name, value in ENGAGEMENT_DEFAULTS[engagement].items():
            if data.get(name) is None and (name != "exit_point" or "exit_point" not in data):
                data[name] = value
        if engagement == "v2":  # step -> window -> games' length and the score's norm
            speed = data.get("intruder_speed", 1.0)
            speed = speed if isinstance(speed, (int, float)) and not isinstance(speed, bool) and speed > 0 else 1.0
            if data.get("step_seconds") is None:
                data["step_seconds"] = CELL_SIDE / speed
            if data.get("tau") is None:
                data["tau"] = data["step_seconds"]
            for name in ("t_max", "capture_time_norm"):
                if data.get(name) is None:
                    data[name] = data["tau"]
        return data

    @model_validator(mode="after")
    def _coupled(self):
        if self.engagement == "v1":
            if self.step_seconds is not None:
                raise ValueError("step_seconds: only engagement v2 ties the step to a cell crossing; "
                                 "leave it out under v1")
        else:
            if abs(self.tau - self.step_seconds) > 1e-9 * self.step_seconds:
                raise ValueError(f"tau: under engagement v2 the window is the step (step_seconds = "
                                 f"{self.step_seconds:g} s), got {self.tau:g} (for the earlier model, set "
                                 f"engagement: v1)")
        if self.t_max < self.tau - 1e-9:
            raise ValueError(f"t_max: the games ({self.t_max:g} s) must last the window tau ({self.tau:g} s)")
        return self

    def window_defaults(self) -> dict:
        """The engagement-dependent settings as resolved: step_seconds, tau, t_max, capture_time_norm."""
        return {k: getattr(self, k) for k in ("step_seconds", "tau", "t_max", "capture_time_norm")}
