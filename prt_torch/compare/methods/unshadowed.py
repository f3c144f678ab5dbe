"""``unshadowed``: the player's unoccluded hemisphere visibility, a constant (no self-shadowing)."""

from __future__ import annotations

import numpy as np

from prt_torch.compare.methods import CompareRun, FrameBatch, FrameSet, MethodBase, register


@register
class Unshadowed(MethodBase):
    """The SH of the upper-hemisphere indicator in every vertex frame (``player.lighting.hemisphere_visibility``)."""

    name = "unshadowed"
    output = "visibility"
    runtime = "constant"

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.eval.shipping import unshadowed_visibility

        self.h = unshadowed_visibility(run.order)
        self.n_vertices = run.n_vertices

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        return np.broadcast_to(self.h, (len(batch.index), self.n_vertices, self.h.shape[0]))

    def bytes(self) -> int:
        return int(self.h.nbytes)
