"""Rotation of SH lighting: ``rotate_lighting(sh, R)`` returns the coefficients of ``L(R^T w)``.

``R`` is a world-frame rotation (z up); the rotated environment is the original one turned by ``R``
(a light from direction ``d`` comes from ``R d`` afterwards). The SH rotation matrices come from
:func:`prt_torch.sh.rotation.sh_rotation` (imported lazily).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import order_from_coeffs
from prt_torch.shapes import check_shape


def check_rotation(R: object, name: str = "rotation") -> np.ndarray:
    """Validate a ``(3, 3)`` proper rotation matrix (orthonormal, det +1); returns float64."""
    r = np.asarray(R, dtype=np.float64)
    check_shape(r, "3 3", name=name)
    if not np.isfinite(r).all():
        raise PrtError(f"{name} contains NaN or Inf")
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    if err > 1e-5 or np.linalg.det(r) < 0:
        raise PrtError(f"{name} must be a proper rotation (R R^T = I, det +1); orthonormality error {err:.3g}")
    return r


def check_lighting(sh: object, name: str = "lighting") -> np.ndarray:
    """Validate SH lighting ``(C, 3)`` (C a square) with finite values; returns float64."""
    a = np.asarray(sh)
    check_shape(a, "C 3", name=name)
    order_from_coeffs(a.shape[0])
    if not np.isfinite(a).all():
        raise PrtError(f"{name} contains NaN or Inf")
    return a.astype(np.float64)


def rotate_lighting(sh: object, R: object) -> np.ndarray:
    """Rotate SH lighting ``(C, 3)`` by the world rotation ``R (3, 3)``: result ``D(R) @ sh``, float64."""
    lighting = check_lighting(sh)
    r = check_rotation(R)
    from prt_torch.sh.rotation import sh_rotation

    D = sh_rotation(r, order_from_coeffs(lighting.shape[0]))
    if not isinstance(D, np.ndarray):  # a torch tensor
        D = D.detach().cpu().numpy()
    return np.asarray(D, dtype=np.float64) @ lighting
