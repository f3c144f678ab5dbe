"""Train section of a run config (owned by :mod:`prt_torch.fit`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class TrainConfig(BaseModel):
    """Reduction and regression settings."""

    model_config = ConfigDict(extra="forbid")

    kinds: list[str] = Field(default_factory=lambda: ["linear", "quadratic", "mlp"])
    input_variance: float = Field(default=0.90, gt=0, le=1)
    output_variance: float = Field(default=0.95, gt=0, le=1)
    folds: int = Field(default=4, ge=2)
    alphas: list[float] = Field(default_factory=lambda: [1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])
    neurons: list[int] = Field(default_factory=lambda: [4, 8, 16])
    max_iter: int = Field(default=500, ge=1)
    seed: int = 0
