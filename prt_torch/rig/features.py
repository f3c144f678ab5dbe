"""Pose features: each joint's rotation relative to its bind pose in the continuous 6D representation.

For joint ``j`` with local rotation ``R_j`` and bind local rotation ``B_j`` the feature is the first
two columns of ``B_j^T R_j`` (Zhou et al. 2019, "On the continuity of rotation representations"):
6 numbers, continuous (no Euler wrap-around or gimbal lock), and the bind pose maps to the
constant ``(1, 0, 0, 0, 1, 0)``. The root joint(s) (``parents == -1``) are excluded: root
translation and orientation move the whole body rigidly, and local-frame visibility is invariant
to that. Joints that never move give constant columns (PCA drops them later).

Layout: ``features[f, 6*i : 6*i + 6] = (c0x, c0y, c0z, c1x, c1y, c1z)`` for the ``i``-th non-root
joint in index order, so ``A = 6 * (number of non-root joints)``.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.exact import small_matmul
from prt_torch.rig.rotations import rotation_part

FEATURES_PER_JOINT = 6


def pose_features(local_rot: np.ndarray, bind_rot: np.ndarray, parents: np.ndarray | None = None,
                  exclude_root: bool = True) -> np.ndarray:
    """6D pose features ``(F, A)`` float32 from local rotations ``(F, J, 3, 3)`` and bind rotations ``(J, 3, 3)``.

    ``local_rot`` / ``bind_rot`` may also be full ``(…, 4, 4)`` transforms (their rotation part is
    used, scale removed). With ``exclude_root`` the roots are dropped: joints with ``parents == -1``
    when ``parents`` is given, else joint 0.
    """
    local_rot = np.asarray(local_rot, dtype=np.float64)
    bind_rot = np.asarray(bind_rot, dtype=np.float64)
    check(local_rot.ndim == 4 and local_rot.shape[-2:] in ((3, 3), (4, 4)),
          f"local rotations must be (F, J, 3, 3), got {local_rot.shape}")
    j = local_rot.shape[1]
    check(bind_rot.shape in ((j, 3, 3), (j, 4, 4)), f"bind rotations must be ({j}, 3, 3), got {bind_rot.shape}")
    check(bool(np.all(np.isfinite(local_rot))), "local rotations contain NaN or inf")
    rel = small_matmul(np.swapaxes(rotation_part(bind_rot), -1, -2)[None], rotation_part(local_rot))  # (F, J, 3, 3)
    keep = np.ones(j, dtype=bool)
    if exclude_root:
        if parents is None:
            keep[0] = False
        else:
            keep &= np.asarray(parents) >= 0
    six = np.concatenate([rel[..., :, 0], rel[..., :, 1]], axis=-1)[:, keep]  # (F, J', 6)
    return six.reshape(six.shape[0], -1).astype(np.float32)


def features_to_rotations(features: np.ndarray) -> np.ndarray:
    """Inverse map (Gram-Schmidt): features ``(F, 6*J')`` -> bind-relative rotations ``(F, J', 3, 3)``."""
    features = np.asarray(features, dtype=np.float64)
    check(features.ndim == 2 and features.shape[1] % FEATURES_PER_JOINT == 0,
          f"features must be (F, 6*J), got {features.shape}")
    six = features.reshape(features.shape[0], -1, 6)
    a, b = six[..., :3], six[..., 3:]
    c0 = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b - np.sum(c0 * b, axis=-1, keepdims=True) * c0
    c1 = b / np.linalg.norm(b, axis=-1, keepdims=True)
    c2 = np.cross(c0, c1)
    return np.stack([c0, c1, c2], axis=-1)
