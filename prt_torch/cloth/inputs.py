"""The deformable input features of a frame (the dataset's ``pose`` column of a cloth run): the ONE rule.

``cloth_features(positions, edges, body_features)`` = the signed dihedral angles (radians) of every interior
edge of the cloth (:func:`prt_torch.deform.dihedral.dihedral_angles`, consistent orientation, 0 for a flat
pair), followed, for the cape with ``cloth.append_pose``, by the body's pose features of that frame
(:attr:`prt_torch.rig.character.Poses.features`). Seed 003 section 5.1: "for cloth simulations we use the full
set of dihedral angles as the current state" (then input PCA, ~90 %).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check


def cloth_features(positions: np.ndarray, edges: np.ndarray, body_features: np.ndarray | None = None) -> np.ndarray:
    """``(..., E [+ A])`` float32 features.

    Args:
        positions: ``(..., V, 3)`` subject positions.
        edges: ``(E, 4)`` interior cloth edges ``(i, j, k, l)`` in subject indices
            (:attr:`prt_torch.cloth.subject.ClothSubject.cloth_edges`).
        body_features: ``(..., A)`` body pose features of the same frames, or ``None``.
    """
    from prt_torch.deform.dihedral import dihedral_angles

    ang = np.asarray(dihedral_angles(np.asarray(positions), np.asarray(edges)), dtype=np.float32)
    if body_features is None:
        return ang
    b = np.asarray(body_features, dtype=np.float32)
    check(b.shape[:-1] == ang.shape[:-1], f"body features {b.shape} do not match the frames of the positions "
                                          f"{np.shape(positions)}")
    return np.concatenate([ang, b], axis=-1)
