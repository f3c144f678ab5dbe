"""Bake section of a run config (owned by :mod:`prt_torch.bake`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from prt_torch import limits as L
from prt_torch.conventions import BelowHorizon


class SubsurfaceConfig(BaseModel):
    """Dipole subsurface material (Jensen et al. 2001; :mod:`prt_torch.bake.subsurface`): coefficients in 1/mm,
    ``scale`` mm per world unit; defaults: Jensen's skin1, green channel, a character in metres."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    sigma_a: float = Field(default=0.17, gt=0, le=1e4)  # absorption, 1/mm
    sigma_s_prime: float = Field(default=0.88, gt=0, le=1e4)  # reduced scattering, 1/mm
    eta: float = Field(default=1.3, ge=1.0, le=3.0)  # relative index of refraction
    scale: float = Field(default=1000.0, gt=0, le=1e6)  # mm per world unit
    cutoff: float = Field(default=6.0, gt=0, le=50.0)  # kernel radius in diffusion lengths 1/sigma_tr
    single: bool = True  # add single scattering to the dipole's multiple scattering


class BakeConfig(BaseModel):
    """How to ray-trace the ground truth.

    Every field that changes the baked numbers (``order``, ``n_rays``, ``below_horizon``, ``transfer*``,
    ``bounces``, ``albedo``, ``seed``, ``ray_offset``, the clustering fields) is recorded in the dataset and
    checked on resume; ``frames_per_task``, ``workers``, ``scheduler`` and ``vertex_chunk`` only
    change how the work is split, never the result.

    Every number is finite and bounded (:mod:`prt_torch.limits`); the memory of one task
    (``frames_per_task`` frames of the character) is checked where the vertex count is known
    (:class:`prt_torch.config.RunConfig` for the built-in character).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    order: int = Field(default=4, ge=1, le=6)  # SH order of local-frame visibility
    n_rays: int = Field(default=512, ge=16, le=L.MAX_RAYS)  # hemisphere rays per vertex
    #: visibility below the horizon (no ray is shot there): "one" (seed 003 eq. 1, an unoccluded vertex is the
    #: constant 1; the default: measured closer to the full-integral reference, docs/DESIGN.md) or "zero"; recorded
    #: in the dataset, which every reader follows (a store without it is "zero")
    below_horizon: BelowHorizon = "one"
    transfer: bool = False  # also bake global-frame cosine-weighted diffuse transfer
    transfer_order: int = Field(default=6, ge=1, le=8)
    bounces: int = Field(default=0, ge=0, le=3)  # diffuse interreflection bounces (transfer only)
    albedo: float = Field(default=0.6, gt=0, lt=1)  # diffuse albedo for interreflection
    frames_per_task: int = Field(default=8, ge=1, le=L.MAX_FRAMES_PER_TASK)  # zarr chunk = one task's block of frames
    workers: int = Field(default=0, ge=0, le=L.MAX_WORKERS)  # 0: one per CPU core
    scheduler: str | None = Field(default=None, max_length=L.MAX_STRING_LENGTH)  # dask scheduler address, e.g. tcp://127.0.0.1:8786
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)
    #: ray origins are offset along the normal by this fraction of the rest mesh's bounding-box diagonal
    ray_offset: float = Field(default=1e-4, gt=0, lt=0.05)
    #: mean-shift bandwidth in skinning-weight space (pure single-bone vertices are sqrt(2) apart, so 0.45 keeps
    #: bones apart and gives blend zones their own clusters); None: sklearn estimate_bandwidth, clamped to 0.2..0.5
    cluster_bandwidth: float | None = Field(default=0.45, gt=0, le=10.0)
    #: at most this many local-frame clusters (the smallest are merged into their nearest neighbour)
    max_clusters: int = Field(default=64, ge=1, le=L.MAX_CLUSTERS)
    #: clusters with fewer vertices than this are merged into their nearest neighbour
    min_cluster_size: int = Field(default=8, ge=1, le=L.MAX_VERTICES)
    #: rays traced per Embree call (bounds memory: 12 bytes per ray per buffer)
    vertex_chunk_rays: int = Field(default=1 << 20, ge=1024, le=L.MAX_CHUNK_RAYS)
    #: sphere blockers fitted on the rest mesh, shipped by ``prt export`` (SHEXP, seed 003 sec. 7; not a baked number)
    blockers: int = Field(default=48, ge=1, le=1024)
    #: also bake per-vertex transfer matrices (seed 001; :mod:`prt_torch.s001.bake`), local frame rows
    transfer_matrix: bool = False
    matrix_order: int = Field(default=4, ge=1, le=8)  # SH order of the transfer matrices (C = order^2)
    matrix_bounces: int = Field(default=1, ge=0, le=2)  # diffuse interreflection bounces in the matrices
    #: also bake the subsurface exit-radiance transfer (dipole + single scattering; needs ``transfer``)
    subsurface: SubsurfaceConfig | None = None

    @model_validator(mode="after")
    def _matrix_keys(self) -> BakeConfig:
        if self.subsurface is not None and not self.transfer:
            raise ValueError("bake.subsurface needs bake.transfer: true (it integrates the irradiance transfer)")
        if self.subsurface is not None and self.transfer_matrix and self.transfer_order < self.matrix_order:
            raise ValueError(f"bake.subsurface with transfer matrices needs transfer_order >= matrix_order, got "
                             f"{self.transfer_order} < {self.matrix_order}")
        return self

    @field_validator("scheduler")
    @classmethod
    def _scheduler(cls, v: str | None) -> str | None:
        return None if v is None else L.check_scheduler(v)
