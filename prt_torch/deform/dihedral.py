"""Signed dihedral angles of interior edges (the deformable input features, seed 003 section 5.1). numpy only.

For an edge row ``(i, j, k, l)`` (:func:`prt_torch.deform.mesh.interior_edges`: faces ``(i, j, k)`` and
``(j, i, l)``, consistently oriented, counter-clockwise seen from the normal side) with ``e = x_j - x_i``::

    n1 = (x_j - x_i) x (x_k - x_i)        # normal of face (i, j, k)
    n2 = (x_i - x_j) x (x_l - x_j)        # normal of face (j, i, l)
    theta = atan2(((n2 x n1) . e) / |e|, n1 . n2)     in (-pi, pi]   (-pi is mapped to +pi)

``theta`` is the angle between the two face normals, i.e. how far the pair is bent out of flat (0 for a
flat pair). Sign: ``theta > 0`` when the two faces fold TOWARD the side their normals point to (the surface is
concave seen from the normal side: a valley); ``theta < 0`` when they fold away from it (a ridge: every edge
of a convex closed mesh with outward normals has ``theta < 0``). The value does not depend on which of the two
faces is listed first: swapping ``(i, j, k, l) -> (j, i, l, k)`` flips both ``e`` and ``n2 x n1``. It is
invariant under rigid motions (rotation + translation) and uniform scaling. A degenerate (zero-area) face
gives ``atan2(0, 0) = 0``: no NaN. The ONNX pre-processing computes the same rule:
:class:`prt_torch.deform.dihedral_torch.DihedralAngles`.
"""

from __future__ import annotations

import numpy as np

from prt_torch.deform.dihedral_soa import DihedralSoA, check_edges
from prt_torch.errors import PrtError


def _dtype(positions: np.ndarray) -> np.dtype:
    return np.dtype(np.float32) if positions.dtype in (np.float16, np.float32) else np.dtype(np.float64)


def dihedral_angles(positions: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Signed dihedral angles (radians, module docstring) of every edge row, vectorised over leading dims.

    Args:
        positions: ``(..., V, 3)`` vertex positions (float32 stays float32, anything else becomes float64).
        edges: ``(E, 4)`` rows ``(i, j, k, l)`` from :func:`prt_torch.deform.mesh.interior_edges`.

    Returns:
        ``(..., E)`` angles in ``(-pi, pi]``, dtype as above.
    """
    x = np.asarray(positions)
    if x.ndim < 2 or x.shape[-1] != 3:
        raise PrtError(f"positions must have shape (..., V, 3), got {x.shape}")
    x = x.astype(_dtype(x), copy=False)
    e = check_edges(edges, x.shape[-2])
    if e.shape[0] == 0:
        return np.zeros((*x.shape[:-2], 0), x.dtype)
    v = x.shape[-2]
    soa = np.moveaxis(x.reshape(-1, v, 3), -1, 1)  # (B, 3, V)
    return DihedralSoA(e, v)(soa).reshape(*x.shape[:-2], e.shape[0])
