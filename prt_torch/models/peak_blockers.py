"""Learned peak blockers (issue 27, ``peaks_learned``): sphere blockers fitted to ray-traced peak visibility.

A peak light's soft shadow at a vertex is the visible fraction of its disc. The analytic cone-sphere kernel
(:func:`prt_torch.blockers.cones.sphere_peak_visibility`) computes it exactly for a set of spheres carried by the
bones; the rest-mesh spheres (:func:`prt_torch.blockers.spheres.fit_spheres`, a quantile radius of k-means
clusters of surface points) are a guess at the body's volume. This model keeps the kernel -- so its cost, its
penumbra and its exported graph are the spheres' -- and *learns* every sphere's rest centre and radius from the
bake's exact peak visibility over poses and light directions (``bake.peaks``: :func:`prt_torch.bake.peaks.
record_frame`), by gradient descent through the kernel (:func:`prt_torch.fit.peaks.fit_peak_blockers`). The
visibility is thus a function of the pose (the skinning matrices carry the spheres) and of the peak's direction
relative to the character, as the issue asks, with a closed-form penumbra for any disc size.

:class:`PeakBlockers` (``nn.Module``): ``forward(positions (B, V, 3), normals (B, V, 3), skin (B, J, 4, 4),
directions (P, 3), angular_radii (P,)) -> (B, V, P)`` in ``[0, 1]``; :meth:`PeakBlockers.sphere_set` gives the
fitted :class:`~prt_torch.blockers.spheres.SphereSet` (the shipped ``peak_blockers.npz``, the player's numba path).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from prt_torch.blockers.cones import sphere_peak_visibility
from prt_torch.blockers.spheres import SphereSet
from prt_torch.shapes import check_shape

#: the learned radius stays within this factor of the initial one (a sphere cannot vanish or swallow the body)
RADIUS_RANGE = (0.25, 4.0)


class PeakBlockers(nn.Module):
    """Sphere blockers with learnable rest centres and radii (module doc).

    Args:
        spheres: the initial set (its bones fixed; centres and radii are learned).
    """

    def __init__(self, spheres: SphereSet) -> None:
        super().__init__()
        self.register_buffer("bone", torch.as_tensor(np.asarray(spheres.bone), dtype=torch.int64))
        self.register_buffer("radius0", torch.as_tensor(np.asarray(spheres.radius), dtype=torch.float32))
        self.register_buffer("center0", torch.as_tensor(np.asarray(spheres.center), dtype=torch.float32).clone())
        #: the centre's move from the initial one, in units of the initial radius (well-scaled for any character)
        self.offset = nn.Parameter(torch.zeros(len(spheres.radius), 3))
        self.log_scale = nn.Parameter(torch.zeros(len(spheres.radius)))
        self.radius_quantile = float(spheres.radius_quantile)

    @property
    def radius(self) -> torch.Tensor:
        """``(S,)`` radii: the initial ones times ``exp(log_scale)``, clamped to :data:`RADIUS_RANGE`."""
        lo, hi = np.log(RADIUS_RANGE[0]), np.log(RADIUS_RANGE[1])
        return self.radius0 * torch.exp(self.log_scale.clamp(lo, hi))

    @property
    def center(self) -> torch.Tensor:
        """``(S, 3)`` rest centres: the initial ones plus ``offset`` x the initial radii."""
        return self.center0 + self.offset * self.radius0[:, None]

    def posed_centers(self, skin: torch.Tensor) -> torch.Tensor:
        """``(B, S, 3)`` posed centres ``skin[bone] @ [center, 1]`` of ``skin (B, J, 4, 4)``."""
        m = skin[:, self.bone]  # (B, S, 4, 4)
        return torch.einsum("bsij,sj->bsi", m[..., :3, :3], self.center) + m[..., :3, 3]

    def forward(self, positions: torch.Tensor, normals: torch.Tensor, skin: torch.Tensor, directions: torch.Tensor,
                angular_radii: torch.Tensor) -> torch.Tensor:
        """``(B, V, P)`` visible fraction of each peak's disc (:func:`~prt_torch.blockers.cones.
        sphere_peak_visibility` of the posed learned spheres)."""
        dims = check_shape(positions, "B V 3", name="peak blockers: positions")
        check_shape(skin, "B J 4 4", name="peak blockers: skin matrices", dims=dims)
        return sphere_peak_visibility(positions, normals, self.posed_centers(skin.to(positions.dtype)), self.radius,
                                      directions, angular_radii)

    def sphere_set(self) -> SphereSet:
        """The fitted spheres as a :class:`SphereSet` (rest centres, radii), what ships."""
        with torch.no_grad():
            return SphereSet(self.bone.cpu().numpy(), self.center.detach().cpu().numpy().astype(np.float32),
                             self.radius.cpu().numpy().astype(np.float32), self.radius_quantile)
