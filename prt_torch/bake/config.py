"""Bake section of a run config (owned by :mod:`prt_torch.bake`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class BakeConfig(BaseModel):
    """How to ray-trace the ground truth.

    Every field that changes the baked numbers (``order``, ``n_rays``, ``transfer*``, ``bounces``,
    ``albedo``, ``seed``, ``ray_offset``, the clustering fields) is recorded in the dataset and
    checked on resume; ``frames_per_task``, ``workers``, ``scheduler`` and ``vertex_chunk`` only
    change how the work is split, never the result.
    """

    model_config = ConfigDict(extra="forbid")

    order: int = Field(default=4, ge=1, le=6)  # SH order of local-frame visibility
    n_rays: int = Field(default=512, ge=16)  # hemisphere rays per vertex
    transfer: bool = False  # also bake global-frame cosine-weighted diffuse transfer
    transfer_order: int = Field(default=6, ge=1, le=8)
    bounces: int = Field(default=0, ge=0, le=3)  # diffuse interreflection bounces (transfer only)
    albedo: float = Field(default=0.6, gt=0, lt=1)  # diffuse albedo for interreflection
    frames_per_task: int = Field(default=8, ge=1)  # zarr chunk = one task's block of frames
    workers: int = Field(default=0, ge=0)  # 0: one per CPU core
    scheduler: str | None = None  # dask scheduler address, e.g. tcp://127.0.0.1:8786
    seed: int = 0
    #: ray origins are offset along the normal by this fraction of the rest mesh's bounding-box diagonal
    ray_offset: float = Field(default=1e-4, gt=0, lt=0.05)
    #: mean-shift bandwidth in skinning-weight space (pure single-bone vertices are sqrt(2) apart, so 0.45 keeps
    #: bones apart and gives blend zones their own clusters); None: sklearn estimate_bandwidth, clamped to 0.2..0.5
    cluster_bandwidth: float | None = Field(default=0.45, gt=0)
    #: at most this many local-frame clusters (the smallest are merged into their nearest neighbour)
    max_clusters: int = Field(default=64, ge=1)
    #: clusters with fewer vertices than this are merged into their nearest neighbour
    min_cluster_size: int = Field(default=8, ge=1)
    #: rays traced per Embree call (bounds memory: 12 bytes per ray per buffer)
    vertex_chunk_rays: int = Field(default=1 << 20, ge=1024)
