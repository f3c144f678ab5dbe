"""Sphere blockers carried by the bones of a character (seed 003 section 7, Ren et al. 2006).

A :class:`SphereSet` is fitted once on the rest mesh (:func:`fit_spheres`):

* every vertex belongs to the bone of its largest skin weight (its *skinning region*);
* ``n_spheres`` are allotted to the bones in proportion to their vertex counts (largest-remainder
  apportionment), at least one per bone that has vertices and at most one per vertex; with fewer
  spheres than such bones, k-means runs over the whole mesh instead and each sphere goes to the
  bone most of its members belong to;
* k-means (scikit-learn, k-means++ seeding, fixed seed) over each bone's vertices gives the centres;
* **radius rule** (a robust quantile radius): ``r = quantile_q(|x_i - c|)`` over the cluster's members
  ``x_i``, ``q = radius_quantile``. At least a fraction ``q`` of each cluster's vertices lies inside its
  sphere (``q = 1``: every one, a covering sphere). The members are SURFACE points, so a covering sphere of a
  cluster stretched along a limb is far bigger than the solid it stands for (radius ~ half the cluster's
  length instead of the limb's radius) and over-occludes; a low quantile gives about the limb's own radius.
  Default ``q = 0.15``, measured on the built-in character (runs/demo, 48 spheres, 3 held-out frames,
  local-frame SH error vs the Embree bake): q = 0.15: 0.154, 0.3: 0.168, 0.5: 0.212, 0.7: 0.266, 0.9: 0.332,
  1.0: 0.406 (unshadowed: 0.282); q = 0 (nearest member, inscribed) under-occludes: 0.172.

Centres are stored in rest-pose world coordinates; a sphere is carried rigidly by its bone, so its
posed centre is ``skin_j @ c`` with the skinning matrix ``skin_j = world_j @ inverse_bind_j``
(:attr:`prt_torch.rig.character.Poses.skin`, what LBS uses). Radii do not change with the pose.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.io import atomic_write_bytes, read_npz_with_meta
from prt_torch.shapes import check_shape

FORMAT = "prt_torch.spheres/1"
DEFAULT_SPHERES = 48
DEFAULT_RADIUS_QUANTILE = 0.15


@dataclass
class SphereSet:
    """Sphere blockers: ``bone (S,)`` int64 carrying joint, ``center (S, 3)`` float32 rest-pose world
    centre, ``radius (S,)`` float32 (world units)."""

    bone: np.ndarray
    center: np.ndarray
    radius: np.ndarray
    radius_quantile: float = DEFAULT_RADIUS_QUANTILE

    def __post_init__(self) -> None:
        bone = np.asarray(self.bone)
        center = np.asarray(self.center)
        radius = np.asarray(self.radius)
        check(bone.ndim == 1 and bone.size >= 1 and np.issubdtype(bone.dtype, np.integer),
              f"sphere bones must be a non-empty (S,) integer array, got {bone.shape} {bone.dtype}")
        s = bone.size
        check_shape(center, (s, 3), name="sphere centres")
        check_shape(radius, (s,), name="sphere radii")
        check(bool(np.isfinite(center).all()), "sphere centres contain NaN or Inf")
        check(bool(np.isfinite(radius).all() and (radius > 0).all()), "sphere radii must be finite and > 0")
        check(bool((bone >= 0).all()), "sphere bones must be >= 0")
        self.bone = bone.astype(np.int64)
        self.center = center.astype(np.float32)
        self.radius = radius.astype(np.float32)

    @property
    def num_spheres(self) -> int:
        """``S``."""
        return int(self.bone.size)

    def to_bytes(self) -> bytes:
        """The ``.npz`` file content."""
        buf = io.BytesIO()
        meta = json.dumps({"format": FORMAT, "radius_quantile": float(self.radius_quantile)})
        np.savez(buf, meta=np.array(meta), bone=self.bone, center=self.center, radius=self.radius)
        return buf.getvalue()

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write an ``.npz`` atomically."""
        atomic_write_bytes(path, self.to_bytes())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SphereSet:
        """Read a file written by :meth:`save`."""
        data, meta = read_npz_with_meta(path, "sphere set")
        check(meta.get("format") == FORMAT, f"unsupported sphere set format {meta.get('format')!r}: {path}")
        return cls(data["bone"], data["center"], data["radius"], float(meta.get("radius_quantile",
                                                                              DEFAULT_RADIUS_QUANTILE)))


def vertex_bones(joints: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(V,)`` int64: the joint of each vertex's largest skin weight (its skinning region)."""
    return np.asarray(joints)[np.arange(joints.shape[0]), np.asarray(weights).argmax(1)].astype(np.int64)


def _apportion(counts: np.ndarray, total: int) -> np.ndarray:
    """Largest-remainder split of ``total`` over bones with ``counts > 0``: >= 1 each, <= count each."""
    nz = counts > 0
    alloc = np.zeros_like(counts)
    alloc[nz] = 1
    rest = total - int(nz.sum())
    cap = counts - alloc
    while rest > 0 and cap.sum() > 0:
        share = counts * (total / counts.sum()) - alloc
        share = np.where(cap > 0, share, -np.inf)
        k = min(rest, int(cap.sum()))
        # give one sphere to each of the k bones furthest below their proportional share
        order = np.argsort(-share, kind="stable")[:k]
        order = order[np.isfinite(share[order])]
        alloc[order] += 1
        cap = counts - alloc
        rest -= order.size
    return alloc


def _kmeans(points: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    from sklearn.cluster import KMeans

    if k >= points.shape[0]:
        return points.astype(np.float64), np.arange(points.shape[0])
    km = KMeans(n_clusters=k, n_init=3, random_state=seed).fit(points.astype(np.float64))
    return km.cluster_centers_, km.labels_


def _radius(points: np.ndarray, center: np.ndarray, q: float) -> float:
    d = np.linalg.norm(points - center, axis=1)
    return float(np.quantile(d, q)) if d.size else 0.0


def fit_spheres(character: Any, n_spheres: int = DEFAULT_SPHERES, seed: int = 0,
                radius_quantile: float = DEFAULT_RADIUS_QUANTILE, min_radius: float | None = None) -> SphereSet:
    """Fit ``n_spheres`` bone-carried spheres to ``character``'s rest mesh (module doc for the rules).

    Args:
        character: a :class:`prt_torch.rig.character.Character` (``rest_vertices``, ``joints``, ``weights``).
        n_spheres: ``S >= 1``.
        seed: k-means seed.
        radius_quantile: ``q`` in [0, 1] of the radius rule (0: the nearest member, an inscribed sphere).
        min_radius: floor on radii (default: 1e-3 of the rest mesh's bounding-box diagonal), so single-vertex
            clusters still block something.
    """
    check(isinstance(n_spheres, (int, np.integer)) and not isinstance(n_spheres, bool) and n_spheres >= 1,
          f"sphere count must be an integer >= 1, got {n_spheres!r}")
    check(isinstance(radius_quantile, (int, float)) and 0.0 <= radius_quantile <= 1.0,
          f"radius_quantile must be in [0, 1], got {radius_quantile!r}")
    verts = np.asarray(character.rest_vertices, dtype=np.float64)
    check_shape(verts, "V 3", name="rest vertices")
    check(verts.shape[0] >= 1, f"rest vertices must be (V, 3), got {verts.shape}")
    check(bool(np.isfinite(verts).all()), "rest vertices contain NaN or Inf")
    n_spheres = int(n_spheres)
    check(n_spheres <= verts.shape[0], f"sphere count {n_spheres} exceeds the {verts.shape[0]} rest vertices")
    if min_radius is None:
        min_radius = 1e-3 * float(np.linalg.norm(verts.max(0) - verts.min(0)))
    vb = vertex_bones(character.joints, character.weights)
    counts = np.bincount(vb, minlength=int(np.asarray(character.parents).size))
    bones: list[np.ndarray] = []
    centers: list[np.ndarray] = []
    radii: list[float] = []
    if n_spheres < int((counts > 0).sum()):
        cen, lab = _kmeans(verts, n_spheres, seed)
        for k in range(cen.shape[0]):
            members = lab == k
            bones.append(np.array([np.bincount(vb[members]).argmax()]))
            centers.append(cen[k:k + 1])
            radii.append(_radius(verts[members], cen[k], radius_quantile))
    else:
        alloc = _apportion(counts, n_spheres)
        for j in np.flatnonzero(alloc):
            pts = verts[vb == j]
            cen, lab = _kmeans(pts, int(alloc[j]), seed)
            for k in range(cen.shape[0]):
                bones.append(np.array([j]))
                centers.append(cen[k:k + 1])
                radii.append(_radius(pts[lab == k], cen[k], radius_quantile))
    r = np.maximum(np.asarray(radii), min_radius)
    return SphereSet(np.concatenate(bones), np.concatenate(centers), r, float(radius_quantile))


def pose_spheres(spheres: SphereSet, skin_mats: np.ndarray) -> np.ndarray:
    """Posed centres ``(..., S, 3)`` float32: ``skin_mats[..., bone] @ [center, 1]``.

    Args:
        spheres: the set.
        skin_mats: ``(..., J, 4, 4)`` skinning matrices ``world_j @ inverse_bind_j`` (``Poses.skin``).
    """
    m = np.asarray(skin_mats)
    check_shape(m, "... J 4 4", name="skin matrices")
    check(int(spheres.bone.max()) < m.shape[-3],
          f"sphere bone {int(spheres.bone.max())} out of range for {m.shape[-3]} skin matrices")
    check(bool(np.isfinite(m).all()), "skin matrices contain NaN or Inf")
    mb = m[..., spheres.bone, :, :]  # (..., S, 4, 4)
    c = spheres.center.astype(np.float64)
    out = np.einsum("...ij,...j->...i", mb[..., :3, :3], c) + mb[..., :3, 3]
    return out.astype(np.float32)
