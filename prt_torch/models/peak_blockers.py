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

**Capsules** (``PeakBlockers(CapsuleSet)``, :mod:`prt_torch.blockers.capsules`): the same with a segment per
blocker, each endpoint learned like a centre (offsets in units of the initial radius), the radius likewise, through
:func:`prt_torch.blockers.capsule_cones.capsule_peak_visibility`; :meth:`PeakBlockers.blocker_set` gives the fitted
set of either kind (:meth:`PeakBlockers.save`: ``peak_blockers.npz``, whose format string records the kind).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from prt_torch.blockers.capsule_cones import capsule_peak_visibility
from prt_torch.blockers.capsules import CapsuleSet
from prt_torch.blockers.cones import sphere_peak_visibility
from prt_torch.blockers.spheres import SphereSet
from prt_torch.shapes import check_shape

#: the learned radius stays within this factor of the initial one (a sphere cannot vanish or swallow the body)
RADIUS_RANGE = (0.25, 4.0)


class PeakBlockers(nn.Module):
    """Sphere or capsule blockers with learnable rest centres (endpoints) and radii (module doc).

    Args:
        spheres: the initial set, a :class:`SphereSet` or a :class:`CapsuleSet` (its bones fixed; centres or
            endpoints and radii are learned).
    """

    def __init__(self, spheres: SphereSet | CapsuleSet) -> None:
        super().__init__()
        capsules = isinstance(spheres, CapsuleSet)
        #: ``"capsules"`` or ``"spheres"``
        self.kind = "capsules" if capsules else "spheres"
        self.register_buffer("bone", torch.as_tensor(np.asarray(spheres.bone), dtype=torch.int64))
        self.register_buffer("radius0", torch.as_tensor(np.asarray(spheres.radius), dtype=torch.float32))
        start = spheres.a if capsules else spheres.center  # type: ignore[union-attr]
        self.register_buffer("center0", torch.as_tensor(np.asarray(start), dtype=torch.float32).clone())
        #: the centre's (capsules: endpoint a's) move from the initial one, in units of the initial radius
        #: (well-scaled for any character)
        self.offset = nn.Parameter(torch.zeros(len(spheres.radius), 3))
        self.log_scale = nn.Parameter(torch.zeros(len(spheres.radius)))
        if capsules:
            self.register_buffer("end0", torch.as_tensor(np.asarray(spheres.b), dtype=torch.float32).clone())
            #: endpoint b's move, in units of the initial radius
            self.offset_b = nn.Parameter(torch.zeros(len(spheres.radius), 3))
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

    @property
    def end(self) -> torch.Tensor:
        """``(S, 3)`` capsules' rest endpoints b (spheres: the centres)."""
        if self.kind == "spheres":
            return self.center
        return self.end0 + self.offset_b * self.radius0[:, None]

    def posed_centers(self, skin: torch.Tensor, rest: torch.Tensor | None = None) -> torch.Tensor:
        """``(B, S, 3)`` posed centres ``skin[bone] @ [center, 1]`` of ``skin (B, J, 4, 4)`` (``rest``: other rest
        points, e.g. :attr:`end`)."""
        m = skin[:, self.bone]  # (B, S, 4, 4)
        return torch.einsum("bsij,sj->bsi", m[..., :3, :3], self.center if rest is None else rest) + m[..., :3, 3]

    def forward(self, positions: torch.Tensor, normals: torch.Tensor, skin: torch.Tensor, directions: torch.Tensor,
                angular_radii: torch.Tensor) -> torch.Tensor:
        """``(B, V, P)`` visible fraction of each peak's disc (:func:`~prt_torch.blockers.cones.
        sphere_peak_visibility` of the posed learned spheres)."""
        dims = check_shape(positions, "B V 3", name="peak blockers: positions")
        check_shape(skin, "B J 4 4", name="peak blockers: skin matrices", dims=dims)
        skin = skin.to(positions.dtype)
        if self.kind == "capsules":
            return capsule_peak_visibility(positions, normals, self.posed_centers(skin), self.posed_centers(
                skin, self.end), self.radius, directions, angular_radii)
        return sphere_peak_visibility(positions, normals, self.posed_centers(skin), self.radius,
                                      directions, angular_radii)

    def sphere_set(self) -> SphereSet:
        """The fitted spheres as a :class:`SphereSet` (rest centres, radii), what ships."""
        with torch.no_grad():
            return SphereSet(self.bone.cpu().numpy(), self.center.detach().cpu().numpy().astype(np.float32),
                             self.radius.cpu().numpy().astype(np.float32), self.radius_quantile)

    def blocker_set(self) -> SphereSet | CapsuleSet:
        """The fitted blockers, a :class:`CapsuleSet` for capsules, else a :class:`SphereSet`."""
        if self.kind == "spheres":
            return self.sphere_set()
        with torch.no_grad():
            return CapsuleSet(self.bone.cpu().numpy(), self.center.cpu().numpy(), self.end.cpu().numpy(),
                              self.radius.cpu().numpy(), self.radius_quantile)

    def save(self, path: Any) -> None:
        """Write :meth:`blocker_set` (``peak_blockers.npz``; its format string records the kind)."""
        self.blocker_set().save(path)
