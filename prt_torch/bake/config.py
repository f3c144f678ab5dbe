"""Bake section of a run config (owned by :mod:`prt_torch.bake`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class BakeConfig(BaseModel):
    """How to ray-trace the ground truth."""

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
