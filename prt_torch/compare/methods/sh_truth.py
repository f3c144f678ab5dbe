"""``sh_truth``: visibility ray-traced on the fly with the bake's own code and settings (the learning target)."""

from __future__ import annotations

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register


@register
class ShTruth(MethodBase):
    """Embree :func:`prt_torch.bake.trace.trace_frame` per frame, with the dataset's order, rays, seed and ray
    offset (``attrs["bake"]``): for a baked frame it reproduces the stored visibility."""

    name = "sh_truth"
    output = "visibility"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return int(run.bake.get("n_rays", 0)) > 0

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.bake.embree import require_embreex
        from prt_torch.bake.trace import RaySet

        require_embreex()
        b = run.bake
        from prt_torch.bake.store import below_horizon_of

        self.rays = RaySet.make(int(b["n_rays"]), int(b["order"]), run.n_vertices, int(b["seed"]),
                                below_horizon=below_horizon_of(b))
        self.offset = float(b["ray_offset_world"])
        self.max_rays = int(b.get("vertex_chunk_rays", 1 << 20))
        self.faces = np.asarray(run.character.faces)
        self.runtime = f"Embree trace_frame, {self.rays.n_rays} rays per vertex"

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        from prt_torch.bake.trace import trace_frame

        return np.stack([trace_frame(p, f, self.faces, self.rays, self.offset, max_rays=self.max_rays).visibility
                         for p, f in zip(batch.positions, batch.frames, strict=True)])
