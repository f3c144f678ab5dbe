"""``unshadowed``: the player's unoccluded visibility in the dataset's convention, a constant (no self-shadowing)."""

from __future__ import annotations

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register


@register
class Unshadowed(MethodBase):
    """The unoccluded visibility in every vertex frame (``player.lighting.hemisphere_visibility``) in the dataset's
    ``bake.below_horizon`` convention: the upper-hemisphere indicator (``"zero"``) or the constant 1 (``"one"``)."""

    name = "unshadowed"
    output = "visibility"
    runtime = "constant"

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.scoring.lighting import unshadowed_visibility

        self.h = unshadowed_visibility(run.order, run.bake)
        self.n_vertices = run.n_vertices

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        return np.broadcast_to(self.h, (len(batch.index), self.n_vertices, self.h.shape[0]))

    def bytes(self) -> int:
        return int(self.h.nbytes)
