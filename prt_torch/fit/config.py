"""Train section of a run config (owned by :mod:`prt_torch.fit`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from prt_torch import limits as L

#: the model kinds ``prt train`` fits
KINDS: tuple[str, ...] = ("linear", "quadratic", "mlp")


class TrainConfig(BaseModel):
    """Reduction and regression settings.

    ``alphas`` is the ridge grid (linear and quadratic; penalty ``alpha ||W||^2`` on a sum of
    squared errors over frames), ``mlp_alphas`` the grid of seed 003 eq. 13's ``alpha``,
    ``neurons`` the hidden-layer sizes tried; both are chosen per cluster by ``folds``-fold
    blocked cross-validation (``cv_iter`` L-BFGS iterations per CV fit, ``max_iter`` for the final
    fit). ``device`` says where the fit runs (:mod:`prt_torch.fit.device`). ``dataset`` defaults to
    ``<run_dir>/dataset.zarr``. ``default_kind`` must be one of ``kinds`` (when not given and ``mlp`` is not
    fitted, the first of ``kinds``). Every number is finite and bounded (:mod:`prt_torch.limits`).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kinds: list[str] = Field(default_factory=lambda: list(KINDS), max_length=len(KINDS))
    default_kind: str = "mlp"
    input_variance: float = Field(default=0.90, gt=0, le=1)
    output_variance: float = Field(default=0.95, gt=0, le=1)
    output_pca: Literal["cluster", "global"] = "cluster"  # per-cluster (seed 003) or global (seed 000 sec. 5)
    # per-cluster inputs of linear and mlp: "pca" = the shared input PCA (seed 003), "joints" = standardised 6D
    # of the joints skinning the cluster + their parents (needs character.npz beside the dataset; prt_torch.fit.inputs)
    input_selection: Literal["pca", "joints"] = "pca"
    selection_weight: float = Field(default=0.01, ge=0, lt=1)  # skinning weight above which a joint counts
    whiten_inputs: bool = False  # measured: whitening hurts held-out error (noise dims get equal weight)
    folds: int = Field(default=4, ge=2, le=L.MAX_FOLDS)
    # which frames the blocked CV validates on: "all" training frames, or "clips" = only frames of real motion
    # clips (the random-pose clip stays in every training fold and is never a validation block)
    cv_validate: Literal["all", "clips"] = "all"
    alphas: list[float] = Field(default_factory=lambda: [1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0],
                                max_length=L.MAX_LIST_LENGTH)
    mlp_alphas: list[float] = Field(default_factory=lambda: [0.1, 1.0, 10.0, 100.0], max_length=L.MAX_LIST_LENGTH)
    neurons: list[int] = Field(default_factory=lambda: [4, 8, 16], max_length=L.MAX_LIST_LENGTH)
    max_iter: int = Field(default=500, ge=1, le=L.MAX_ITERATIONS)
    cv_iter: int = Field(default=200, ge=1, le=L.MAX_ITERATIONS)
    history_size: int = Field(default=20, ge=2, le=L.MAX_HISTORY)
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)
    # where the ridge solves and the MLP L-BFGS run (prt_torch.fit.device): auto = cuda when torch sees a GPU,
    # else cpu (the float64 reference path); not part of the train stage key when it resolves to cpu
    device: Literal["auto", "cpu", "cuda"] = "auto"
    # torch intra-op threads while fitting (0: leave torch's default)
    threads: int = Field(default=1, ge=0, le=L.MAX_THREADS)
    dataset: str | None = Field(default=None, min_length=1, max_length=L.MAX_STRING_LENGTH)
    eval_frames: int | None = Field(default=None, ge=2, le=L.MAX_FRAMES)  # cap on frames per split in metrics.json

    @field_validator("kinds")
    @classmethod
    def _kinds(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if k not in KINDS]
        if bad or not v:
            raise ValueError(f"unknown model kind(s) {bad}; expected {', '.join(KINDS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"repeated model kind in {v}")
        return v

    @field_validator("alphas", "mlp_alphas")
    @classmethod
    def _alphas(cls, v: list[float]) -> list[float]:
        if not v or any(not 0 <= a <= L.MAX_ALPHA for a in v):
            raise ValueError(f"need a non-empty list of alphas in [0, {L.MAX_ALPHA:g}]")
        return v

    @field_validator("neurons")
    @classmethod
    def _neurons(cls, v: list[int]) -> list[int]:
        if not v or any(not 1 <= n <= L.MAX_NEURONS for n in v):
            raise ValueError(f"need a non-empty list of neuron counts in 1..{L.MAX_NEURONS}")
        return v

    @field_validator("default_kind")
    @classmethod
    def _given_default_kind(cls, v: str, info: ValidationInfo) -> str:
        kinds = info.data.get("kinds")
        if kinds is not None and v not in kinds:
            raise ValueError(f"{v[:64]!r} is not one of kinds {kinds}")
        return v

    @model_validator(mode="after")
    def _default_kind(self) -> TrainConfig:
        if self.default_kind not in self.kinds:  # not given: the first kind fitted
            self.default_kind = self.kinds[0]
        return self
