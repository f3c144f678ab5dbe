"""Train section of a run config (owned by :mod:`prt_torch.fit`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from prt_torch import limits as L

#: the model kinds ``prt train`` fits
KINDS: tuple[str, ...] = ("linear", "quadratic", "mlp")


class TransferConfig(BaseModel):
    """``train.transfer``: learned diffuse transfer (seed 000; :mod:`prt_torch.transfer.fit`). The ``kinds`` are fitted
    to the baked global-frame ``transfer`` (and ``subsurface`` when baked) vectors with the train section's grids:
    input PCA of the poses (``input_components``, else ``input_variance``), output PCA ``global`` (seed 000 sec. 5:
    one basis over the per-coefficient vertex vectors; Table 1's PCA(8, 22) = 8 inputs, 22 outputs) or per
    ``cluster`` (``output_components`` per cluster, else ``output_variance``); ``alpha``: one fixed ridge alpha
    (None: chosen by the blocked CV over ``train.alphas``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kinds: list[str] = Field(default_factory=lambda: ["linear"], max_length=len(KINDS))
    input_components: int | None = Field(default=8, ge=1, le=L.MAX_NEURONS)
    output_components: int | None = Field(default=22, ge=1, le=L.MAX_NEURONS)
    input_variance: float = Field(default=0.90, gt=0, le=1)
    output_variance: float = Field(default=0.95, gt=0, le=1)
    output_pca: Literal["global", "cluster"] = "global"
    alpha: float | None = Field(default=None, ge=0, le=L.MAX_ALPHA)

    @field_validator("kinds")
    @classmethod
    def _kinds(cls, v: list[str]) -> list[str]:
        bad = [k for k in v if k not in KINDS]
        if bad or not v or len(set(v)) != len(v):
            raise ValueError(f"transfer kinds must be distinct kinds of {', '.join(KINDS)}, got {v}")
        return v


class S001Config(BaseModel):
    """``train.s001``: seed 001's compressed transfer matrices (:mod:`prt_torch.s001.fit`). Segments = the skinning
    clusters; per segment the poses of ``clip`` are grouped by recursive normalized cut into groups of
    ``leaf_size`` (eq. 3 with ``t_scale`` / ``p_scale``); CPCA with ``n_basis`` basis matrices per cluster,
    ``clusters_per_segment`` clusters per segment, ``cpca_iters`` reassignment rounds; 16-bit coefficients.
    ``other_bone_weight``: eq. 6 weight of bones that do not skin a segment; ``rbf_scale``: NRBF width / nearest
    distance; ``memory_mb``: the stage's budget for transfer data held at once (it streams the store)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    clip: str = Field(default="random", min_length=1, max_length=L.MAX_STRING_LENGTH)
    leaf_size: int = Field(default=4, ge=2, le=64)
    t_scale: float = Field(default=1.0, gt=0, le=1e6)
    p_scale: float = Field(default=2.0, gt=0, le=1e6)
    n_basis: int = Field(default=8, ge=1, le=64)
    # "segment": row-constrained CPCA per segment (clusters_per_segment clusters, cpca_iters rounds; the default:
    # measured 0.12 train error with 76 clusters vs 0.62 with 265 for "revised" on the same small store);
    # "revised": sec. 4's incremental revised CPCA (prt_torch.s001.rcpca, per-pose budget m_cpf clusters)
    cpca: Literal["revised", "segment"] = "segment"
    m_cpf: int = Field(default=64, ge=1, le=1 << 16)
    clusters_per_segment: int = Field(default=8, ge=1, le=4096)
    cpca_iters: int = Field(default=3, ge=0, le=100)
    other_bone_weight: float = Field(default=0.0, ge=0, le=1)  # eq. 6 weight of bones not skinning the segment
    rbf_scale: float = Field(default=1.0, gt=0, le=100)
    memory_mb: int = Field(default=1024, ge=16, le=1 << 20)
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)


class LocalConfig(BaseModel):
    """``train.local``: local visibility models of a deformable run (:mod:`prt_torch.local.models`, fitted by
    :mod:`prt_torch.local.fit`): one network shared by every vertex, fed its neighbours' offsets in its own frame.
    Neighbours: rings of ``radii`` (world units) x ``angles`` in the rest tangent plane. ``linear``: closed-form
    ridge (``alpha``, relative to the mean squared input) with a per-vertex intercept; ``mlp``: tanh layers of
    ``hidden`` sizes, Adam on ``batch`` random (frame, vertex) samples for ``steps`` steps at ``lr`` (cosine decay),
    seeded by the train section's ``seed``. ``default``: the kind ``prt export`` ships as the run's visibility when
    set (``None``: the per-cluster model of ``train.default_kind`` ships)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kinds: list[Literal["linear", "mlp"]] = Field(default_factory=lambda: ["linear", "mlp"], min_length=1,
                                                  max_length=2)
    # 24 samples and 32 x 32 hidden: on the 7.7k flag held-out 0.212 (40 samples and 64 x 64: 0.203) at 1.8 ms per
    # frame on one core (4.1 ms)
    radii: list[float] = Field(default_factory=lambda: [0.015, 0.04, 0.1, 0.25], min_length=1, max_length=16)
    angles: int = Field(default=6, ge=1, le=64)
    hidden: list[int] = Field(default_factory=lambda: [32, 32], min_length=1, max_length=4)
    steps: int = Field(default=6000, ge=1, le=L.MAX_ITERATIONS)
    batch: int = Field(default=4096, ge=16, le=1 << 20)
    lr: float = Field(default=1e-3, gt=0, le=1.0)
    alpha: float = Field(default=1e-3, ge=0, le=L.MAX_ALPHA)
    default: Literal["linear", "mlp"] | None = None

    @field_validator("radii")
    @classmethod
    def _radii(cls, v: list[float]) -> list[float]:
        if any(not 0 < r <= 1e3 for r in v):
            raise ValueError(f"local radii must be in (0, 1000], got {v}")
        return v

    @field_validator("hidden")
    @classmethod
    def _hidden(cls, v: list[int]) -> list[int]:
        if any(not 1 <= n <= L.MAX_NEURONS for n in v):
            raise ValueError(f"local hidden sizes must be in 1..{L.MAX_NEURONS}, got {v}")
        return v

    @model_validator(mode="after")
    def _default_fitted(self) -> LocalConfig:
        if self.default is not None and self.default not in self.kinds:
            raise ValueError(f"local default {self.default!r} is not one of kinds {self.kinds}")
        if len(set(self.kinds)) != len(self.kinds):
            raise ValueError(f"repeated local kind in {self.kinds}")
        return self


class PeakFitConfig(BaseModel):
    """``train.peaks``: fit the learned peak blockers to the bake's peak visibility (needs ``bake.peaks``;
    :mod:`prt_torch.fit.peaks`, whose module doc explains each setting)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    steps: int = Field(default=400, ge=1, le=L.MAX_ITERATIONS)
    frames_per_step: int = Field(default=8, ge=1, le=1024)
    vertices_per_step: int = Field(default=4096, ge=16, le=L.MAX_VERTICES)
    learning_rate: float = Field(default=0.02, gt=0, le=1.0)
    widen_deg: float = Field(default=4.0, ge=0.05, le=30.0)
    anneal: float = Field(default=0.6, gt=0, le=1.0)
    eval_frames: int = Field(default=16, ge=1, le=L.MAX_FRAMES)
    #: learned spheres (``None``: the run's ``bake.blockers``). 64 measured on the demo character (held-out wave,
    #: 1-degree discs, share of vertex-disc pairs on the wrong side of 0.5): rest spheres 48 / 64 / 96: 2.9 / 3.0 /
    #: 3.5 %, learned 48 (300 steps) / 64 (400) / 96 (400): 1.6 / 1.3 / 1.3 %; 800 steps do not improve 64's
    spheres: int | None = Field(default=64, ge=1, le=1024)
    #: the blockers' kind: ``capsules`` (``capsules_per_bone`` per bone with vertices,
    #: :mod:`prt_torch.blockers.capsules`; ``spheres`` is then unused) or ``spheres``. Measured on the demo
    #: character (all 31 held-out wave frames x 4 one-degree discs, share of vertex-disc pairs on the wrong side of
    #: 0.5 / mean abs. error): rest spheres 48: 2.80 % / 0.028, rest capsules 21: 1.53 % / 0.015, learned spheres
    #: 48 / 64 / 96: 1.55-1.69 / 1.32 / 1.23 % / 0.016 / 0.013 / 0.012, learned capsules 21 (400 steps): 1.14 % /
    #: 0.0115 (42: below)
    blockers: Literal["capsules", "spheres"] = "capsules"
    #: capsules per bone with vertices (``blockers: capsules``; 1: one per bone, more: the bones with most vertices
    #: split along their axes). Measured as above, learned (400 steps): 21 / 30 / 42 / 63 capsules (1 / 1.43 / 2 / 3
    #: per bone): 1.14 / 1.00 / 0.94 / 0.99 % wrong side, 0.0115 / 0.0101 / 0.0095 / 0.0100 mean abs. error (the
    #: rest capsules get worse with splits: 1.53 % at 1 per bone, 2.42 % at 2: the fit moves the pieces); but the
    #: images (prt compare on the demo run, procedural sky, learned_mlp+peaks_learned vs the Monte-Carlo reference,
    #: 4 frames, the sky's 0.265-degree sun): 21 capsules 39.1 dB diffuse, 42: 37.8 dB (learned spheres 48: 32.4,
    #: rest spheres 32.5), and 42 cost 2.6 ms a frame against 1.6 ms (11.7k vertices, one peak, one thread): 1 per bone
    capsules_per_bone: float = Field(default=1.0, ge=1.0, le=8.0)
    #: the loss's weight per vertex-disc pair: ``uniform`` or ``cosine`` (``max(n . l, 0)``, the peak term's factor).
    #: Measured on configs/mocap.yaml's run (held-out jumps + climb, 24 frames x 4 one-degree discs, shading-weighted
    #: RMSE: uniform 0.0390, cosine 0.0344; cosine with 1.5 / 2 capsules per bone 0.0314 / 0.0289), then prt compare
    #: (learned_mlp+peaks_learned vs the Monte-Carlo reference, diffuse image PSNR under the sky / spiaggia / quarry):
    #: uniform 32.2 / 36.8 / 37.3 dB, cosine 33.8 / 35.4 / 36.7 (below peaks_spheres' 37.0 on quarry): uniform
    weight: Literal["cosine", "uniform"] = "uniform"


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
    input_max_components: int | None = Field(default=None, ge=1, le=L.MAX_NEURONS)  # caps the input projection
    output_variance: float = Field(default=0.95, gt=0, le=1)
    output_max_components: int | None = Field(default=None, ge=1, le=L.MAX_NEURONS)  # per cluster: caps model size
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
    transfer: TransferConfig | None = None  # learned diffuse transfer (seed 000), prt_torch.transfer.fit
    s001: S001Config | None = None  # seed 001 compressed transfer matrices, prt_torch.s001.fit
    local: LocalConfig | None = None  # local visibility models of a deformable run, prt_torch.local.fit
    peaks: PeakFitConfig | None = None  # the learned peak blockers (issue 27; needs bake.peaks), prt_torch.fit.peaks

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
