"""Bake section of a run config (owned by :mod:`prt_torch.bake`)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from prt_torch import limits as L
from prt_torch.conventions import BelowHorizon

#: ``absent`` of a :func:`recorded` field every store records (no value for older stores needed)
ALWAYS_RECORDED = object()


def recorded(result: bool = True, absent: Any = ALWAYS_RECORDED) -> dict[str, Any]:
    """``json_schema_extra`` of a :class:`BakeConfig` field the store records in ``attrs["bake"]``.

    Args:
        result: the field changes the baked numbers (compared on resume, :func:`result_keys`).
        absent: its value for a store written before it was recorded (:func:`absent_values`).
    """
    extra: dict[str, Any] = {"recorded": True, "result": bool(result)}
    if absent is not ALWAYS_RECORDED:
        extra["absent"] = absent
    return extra


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


class PeakBakeConfig(BaseModel):
    """``bake.peaks``: record exact peak-light visibility (:func:`prt_torch.bake.peaks.exact_peak_visibility`) of
    every baked frame, the training data of the learned peak blockers (:mod:`prt_torch.models.peak_blockers`).
    Each frame gets ``directions`` disc lights of half-angle ``angular_radius_deg`` toward seeded directions
    uniform over the sky above ``min_elevation_deg`` (world, z up: every root heading), ``disc_side^2`` rays per
    vertex and disc (:func:`prt_torch.bake.peaks.record_directions`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    directions: int = Field(default=4, ge=1, le=32)
    angular_radius_deg: float = Field(default=1.0, ge=0.05, le=30.0)
    disc_side: int = Field(default=3, ge=1, le=16)
    min_elevation_deg: float = Field(default=5.0, ge=-90.0, lt=90.0)


class BakeConfig(BaseModel):
    """How to ray-trace the ground truth.

    The fields marked :func:`recorded` are the store's ``attrs["bake"]`` (:meth:`store_params`, in field order);
    those marked ``result`` change the baked numbers and are compared on resume (:func:`result_keys`:
    ``order``, ``n_rays``, ``below_horizon``, ``transfer*``, ``bounces``, ``albedo``, ``seed``, ``ray_offset``,
    the clustering fields, seed 001's matrices, ``subsurface``); ``vertex_chunk_rays`` is recorded for the
    workers but only bounds memory; ``frames_per_task``, ``workers``, ``scheduler`` and ``blockers`` are not
    recorded there (they change how the work is split, or what export fits, never the baked numbers).

    Every number is finite and bounded (:mod:`prt_torch.limits`); the memory of one task
    (``frames_per_task`` frames of the character) is checked where the vertex count is known
    (:class:`prt_torch.config.RunConfig` for the built-in character).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    order: int = Field(default=4, ge=1, le=6, json_schema_extra=recorded())  # SH order of local-frame visibility
    n_rays: int = Field(default=512, ge=16, le=L.MAX_RAYS, json_schema_extra=recorded())  # hemisphere rays per vertex
    #: visibility below the horizon (no ray is shot there): "one" (seed 003 eq. 1, an unoccluded vertex is the
    #: constant 1; the default: measured closer to the full-integral reference, docs/DESIGN.md) or "zero"; recorded
    #: in the dataset, which every reader follows (a store without it is "zero")
    below_horizon: BelowHorizon = Field(default="one", json_schema_extra=recorded(absent="zero"))
    #: also bake global-frame cosine-weighted diffuse transfer
    transfer: bool = Field(default=False, json_schema_extra=recorded())
    transfer_order: int = Field(default=6, ge=1, le=8, json_schema_extra=recorded())
    #: diffuse interreflection bounces (transfer only)
    bounces: int = Field(default=0, ge=0, le=3, json_schema_extra=recorded())
    albedo: float = Field(default=0.6, gt=0, lt=1, json_schema_extra=recorded())  # diffuse albedo for interreflection
    frames_per_task: int = Field(default=8, ge=1, le=L.MAX_FRAMES_PER_TASK)  # zarr chunk = one task's block of frames
    workers: int = Field(default=0, ge=0, le=L.MAX_WORKERS)  # 0: one per CPU core
    scheduler: str | None = Field(default=None, max_length=L.MAX_STRING_LENGTH)  # dask scheduler address, e.g. tcp://127.0.0.1:8786
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED, json_schema_extra=recorded())
    #: ray origins are offset along the normal by this fraction of the rest mesh's bounding-box diagonal
    ray_offset: float = Field(default=1e-4, gt=0, lt=0.05, json_schema_extra=recorded())
    #: mean-shift bandwidth in skinning-weight space (pure single-bone vertices are sqrt(2) apart, so 0.45 keeps
    #: bones apart and gives blend zones their own clusters); None: sklearn estimate_bandwidth, clamped to 0.2..0.5
    cluster_bandwidth: float | None = Field(default=0.45, gt=0, le=10.0, json_schema_extra=recorded())
    #: at most this many local-frame clusters (the smallest are merged into their nearest neighbour)
    max_clusters: int = Field(default=64, ge=1, le=L.MAX_CLUSTERS, json_schema_extra=recorded())
    #: clusters with fewer vertices than this are merged into their nearest neighbour
    min_cluster_size: int = Field(default=8, ge=1, le=L.MAX_VERTICES, json_schema_extra=recorded())
    #: rays traced per Embree call (bounds memory: 12 bytes per ray per buffer)
    vertex_chunk_rays: int = Field(default=1 << 20, ge=1024, le=L.MAX_CHUNK_RAYS,
                                   json_schema_extra=recorded(result=False))
    #: sphere blockers fitted on the rest mesh, shipped by ``prt export`` (SHEXP, seed 003 sec. 7; not a baked number)
    blockers: int = Field(default=48, ge=1, le=1024)
    #: also bake per-vertex transfer matrices (seed 001; :mod:`prt_torch.s001.bake`), local frame rows
    transfer_matrix: bool = Field(default=False, json_schema_extra=recorded(absent=False))
    #: SH order of the transfer matrices (C = order^2)
    matrix_order: int = Field(default=4, ge=1, le=8, json_schema_extra=recorded(absent=4))
    #: diffuse interreflection bounces in the matrices
    matrix_bounces: int = Field(default=1, ge=0, le=2, json_schema_extra=recorded(absent=1))
    #: also bake the subsurface exit-radiance transfer (dipole + single scattering; needs ``transfer``)
    subsurface: SubsurfaceConfig | None = Field(default=None, json_schema_extra=recorded(absent=None))
    #: also record exact peak-light visibility per frame (issue 27: the learned peak blockers' training data)
    peaks: PeakBakeConfig | None = Field(default=None, json_schema_extra=recorded(absent=None))

    @model_validator(mode="after")
    def _matrix_keys(self) -> BakeConfig:
        if self.subsurface is not None and not self.transfer:
            raise ValueError("bake.subsurface needs bake.transfer: true (it integrates the irradiance transfer)")
        if self.subsurface is not None and self.transfer_matrix and self.transfer_order < self.matrix_order:
            raise ValueError(f"bake.subsurface with transfer matrices needs transfer_order >= matrix_order, got "
                             f"{self.transfer_order} < {self.matrix_order}")
        return self

    def store_params(self) -> dict[str, Any]:
        """The store's ``attrs["bake"]`` entries of this config: every :func:`recorded` field, in field order, as
        JSON (the bake adds ``ray_offset_world``)."""
        data = self.model_dump(mode="json")
        return {k: data[k] for k in recorded_keys()}

    @field_validator("scheduler")
    @classmethod
    def _scheduler(cls, v: str | None) -> str | None:
        return None if v is None else L.check_scheduler(v)


def _marks() -> dict[str, dict[str, Any]]:
    """``{field: its recorded() marker}`` of :class:`BakeConfig`, in field order."""
    out = {}
    for name, info in BakeConfig.model_fields.items():
        extra = info.json_schema_extra
        if isinstance(extra, dict) and extra.get("recorded"):
            out[name] = extra
    return out


def recorded_keys() -> tuple[str, ...]:
    """The :class:`BakeConfig` fields a store records in ``attrs["bake"]``, in field order."""
    return tuple(_marks())


def result_keys() -> tuple[str, ...]:
    """The recorded fields that change the baked numbers (compared on resume), in field order."""
    return tuple(k for k, m in _marks().items() if m["result"])


def absent_values() -> dict[str, Any]:
    """``{field: value}`` for the recorded fields added after stores were written: what a store that does not
    record the field was baked with (e.g. ``below_horizon: "zero"``, not today's default)."""
    return {k: m["absent"] for k, m in _marks().items() if "absent" in m}
