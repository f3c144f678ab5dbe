"""Ground truth for the height field: Embree rays on the same triangle mesh, traced by the bake's own code.

:func:`prt_torch.bake.trace.trace_frame` with the bake's ray set (:meth:`prt_torch.bake.trace.RaySet.make`:
``n_rays`` spherical-Fibonacci hemisphere directions rotated per vertex by seeded angles, projected to SH in
the vertex frame, ``below_horizon`` as the bake), ray origins offset along the normal by
``offset * extent`` (the bake offsets by a fraction of the bounding-box diagonal; the height field's
extent plays that role).
"""

from __future__ import annotations

import numpy as np

from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.heightfield.surface import HeightFieldFrame

#: default rays per vertex (the bake's default) and origin offset (fraction of the extent)
N_RAYS, OFFSET = 512, 1e-4


def truth_visibility(frame: HeightFieldFrame, order: int = 4, n_rays: int = N_RAYS, below_horizon: str = "one",
                     seed: int = 0, offset: float = OFFSET, rays: RaySet | None = None) -> np.ndarray:
    """``(V, C)`` float32 Embree SH visibility of every vertex of ``frame`` in its vertex frame.

    ``rays``: a ray set made once for this vertex count (else made here from ``n_rays``, ``order``,
    ``below_horizon`` and ``seed``)."""
    v = frame.positions.shape[0]
    if rays is None:
        rays = RaySet.make(n_rays, order, v, seed, below_horizon)
    return trace_frame(frame.positions, frame.frames, frame.faces, rays, offset * frame.extent).visibility
