"""The allocation MDP's settings (SPEC.md section 5), one typed model, every default here."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class AllocConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    grid_size: int = Field(3, ge=2, le=32)
    n_defenders: int = Field(100, ge=1, le=100_000)
    n_intruders: int = Field(50, ge=1, le=100_000)
    c_distribution: float = Field(1.0, ge=0, allow_inf_nan=False)
    c_capture: float = Field(0.0, ge=0, allow_inf_nan=False)
    breach_penalty: float = Field(1.0, ge=0, allow_inf_nan=False)
    capture_time_norm: float = Field(10.0, gt=0, allow_inf_nan=False)
    action_map: Literal["softmax", "shifted"] = "softmax"
    softmax_beta: float = Field(5.0, gt=0, allow_inf_nan=False)
    vertical_drift: float = Field(0.0, ge=0, le=0.5)
    max_steps: int = Field(12, ge=1, le=10_000)
    epsilon: float = Field(1e-3, gt=0, lt=1)
    engage_min_mass: float = Field(1e-6, ge=0)
    team_sizes: Literal["exact", "lattice"] = "exact"
    # The PE games behind each engagement (the capture-time service's settings).
    pursuer_policy: str = "area_min"
    evader_policy: str = "centroid"
    tau: float = Field(5.0, gt=0, allow_inf_nan=False)
    t_max: float = Field(10.0, gt=0, allow_inf_nan=False)
    law: Literal["boxes", "uniform"] = "boxes"  # boxes: the paper's start boxes (SPEC.md section 3)
    games: int = Field(64, ge=2, le=100_000)
    seed: int = Field(0, ge=0)
