"""Train section of a run config (owned by :mod:`prt_torch.fit`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class TrainConfig(BaseModel):
    """Reduction and regression settings.

    ``alphas`` is the ridge grid (linear and quadratic; penalty ``alpha ||W||^2`` on a sum of
    squared errors over frames), ``mlp_alphas`` the grid of seed 003 eq. 13's ``alpha``,
    ``neurons`` the hidden-layer sizes tried; both are chosen per cluster by ``folds``-fold
    blocked cross-validation (``cv_iter`` L-BFGS iterations per CV fit, ``max_iter`` for the final
    fit). ``dataset`` defaults to ``<run_dir>/dataset.zarr``.
    """

    model_config = ConfigDict(extra="forbid")

    kinds: list[str] = Field(default_factory=lambda: ["linear", "quadratic", "mlp"])
    default_kind: str = "mlp"
    input_variance: float = Field(default=0.90, gt=0, le=1)
    output_variance: float = Field(default=0.95, gt=0, le=1)
    output_pca: Literal["cluster", "global"] = "cluster"  # per-cluster (seed 003) or global (seed 000 sec. 5)
    # per-cluster inputs of linear and mlp: "pca" = the shared input PCA (seed 003), "joints" = standardised 6D
    # of the joints skinning the cluster + their parents (needs character.npz beside the dataset; prt_torch.fit.inputs)
    input_selection: Literal["pca", "joints"] = "pca"
    selection_weight: float = Field(default=0.01, ge=0, lt=1)  # skinning weight above which a joint counts
    whiten_inputs: bool = False  # measured: whitening hurts held-out error (noise dims get equal weight)
    folds: int = Field(default=4, ge=2)
    alphas: list[float] = Field(default_factory=lambda: [1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0])
    mlp_alphas: list[float] = Field(default_factory=lambda: [0.1, 1.0, 10.0, 100.0])
    neurons: list[int] = Field(default_factory=lambda: [4, 8, 16])
    max_iter: int = Field(default=500, ge=1)
    cv_iter: int = Field(default=200, ge=1)
    history_size: int = Field(default=20, ge=2)
    seed: int = 0
    threads: int = Field(default=1, ge=0)  # torch intra-op threads while fitting (0: leave torch's default)
    dataset: str | None = None
    eval_frames: int | None = Field(default=None, ge=2)  # cap on frames per split in metrics.json

    @field_validator("kinds")
    @classmethod
    def _kinds(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if k not in ("linear", "quadratic", "mlp")]
        if bad or not v:
            raise ValueError(f"unknown model kind(s) {bad}; expected linear, quadratic, mlp")
        return v

    @field_validator("alphas", "mlp_alphas")
    @classmethod
    def _alphas(cls, v: list[float]) -> list[float]:
        if not v or any(a < 0 for a in v):
            raise ValueError("need a non-empty list of alphas >= 0")
        return v

    @field_validator("neurons")
    @classmethod
    def _neurons(cls, v: list[int]) -> list[int]:
        if not v or any(n < 1 for n in v):
            raise ValueError("need a non-empty list of neuron counts >= 1")
        return v
