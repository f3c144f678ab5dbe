"""Capsule blockers carried by the bones of a character (issue 27: the peak lights' soft shadows, what Unreal's
capsule shadows do).

A capsule is a segment ``a-b`` carried rigidly by one bone and a radius ``r``: the points within ``r`` of the
segment. A sphere is a capsule with ``a == b``. A limb is one capsule, not a row of spheres with gaps between them.

A :class:`CapsuleSet` is fitted once on the rest mesh (:func:`fit_capsules`):

* every vertex belongs to the bone of its largest skin weight (:func:`prt_torch.blockers.spheres.vertex_bones`);
* each bone with vertices gets one capsule, or ``k`` of them when ``n_capsules`` exceeds the bone count (the extra
  capsules apportioned to the bones by vertex count, largest remainder, as the spheres are; a bone's vertices are
  split into ``k`` pieces by k-means on their projection onto the bone's principal axis);
* per piece: the principal axis ``u`` of its vertices (PCA about their mean ``m``), their projections ``t_i`` and
  their distances ``d_i`` from the axis line; **radius** ``r = quantile_q(d_i)`` (``q = radius_quantile``: the
  members are SURFACE points, a low quantile gives about the limb's own radius, as for the spheres); the
  **segment** spans the projections' robust range ``[quantile_e(t), quantile_{1-e}(t)]`` (``e = end_quantile``)
  shortened by ``r`` at both ends (so the capsule's round caps end where the vertices do), collapsed to its
  midpoint when shorter than ``2 r``.

Endpoints are stored in rest-pose world coordinates; posed with the bone's skinning matrix ``skin_j = world_j @
inverse_bind_j`` (:func:`pose_capsules`), radii do not change with the pose.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.blockers.spheres import SphereSet, pose_spheres, vertex_bones
from prt_torch.errors import check
from prt_torch.io import atomic_write_bytes, read_npz_with_meta
from prt_torch.shapes import check_shape

FORMAT = "prt_torch.capsules/1"
DEFAULT_RADIUS_QUANTILE = 0.5
DEFAULT_END_QUANTILE = 0.02


@dataclass
class CapsuleSet:
    """Capsule blockers: ``bone (S,)`` int64 carrying joint, ``a (S, 3)``, ``b (S, 3)`` float32 rest-pose world
    segment endpoints, ``radius (S,)`` float32 (world units)."""

    bone: np.ndarray
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    radius_quantile: float = DEFAULT_RADIUS_QUANTILE

    def __post_init__(self) -> None:
        bone, a, b, radius = (np.asarray(x) for x in (self.bone, self.a, self.b, self.radius))
        check(bone.ndim == 1 and bone.size >= 1 and np.issubdtype(bone.dtype, np.integer),
              f"capsule bones must be a non-empty (S,) integer array, got {bone.shape} {bone.dtype}")
        s = bone.size
        check_shape(a, (s, 3), name="capsule endpoints a")
        check_shape(b, (s, 3), name="capsule endpoints b")
        check_shape(radius, (s,), name="capsule radii")
        check(bool(np.isfinite(a).all() and np.isfinite(b).all()), "capsule endpoints contain NaN or Inf")
        check(bool(np.isfinite(radius).all() and (radius > 0).all()), "capsule radii must be finite and > 0")
        check(bool((bone >= 0).all()), "capsule bones must be >= 0")
        self.bone = bone.astype(np.int64)
        self.a = a.astype(np.float32)
        self.b = b.astype(np.float32)
        self.radius = radius.astype(np.float32)

    @property
    def num_capsules(self) -> int:
        """``S``."""
        return int(self.bone.size)

    @classmethod
    def from_spheres(cls, spheres: SphereSet) -> CapsuleSet:
        """Spheres as degenerate capsules (``a == b`` = the centre)."""
        return cls(spheres.bone, spheres.center, spheres.center, spheres.radius, spheres.radius_quantile)

    def spheres(self) -> SphereSet:
        """The capsules as rows of spheres (a :class:`SphereSet` for a consumer that takes only spheres): per capsule
        ``1 + ceil(2 |b - a| / r)`` spheres of radius ``r`` evenly along the segment (consecutive centres at most
        ``r / 2`` apart: no gap wider than 3% of the radius)."""
        length = np.linalg.norm(self.b - self.a, axis=1)
        n = 1 + np.ceil(2 * length / self.radius).astype(np.int64)
        k = np.repeat(np.arange(self.num_capsules), n)
        t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.maximum(np.repeat(n, n) - 1, 1)
        center = self.a[k] + t[:, None].astype(np.float32) * (self.b[k] - self.a[k])
        return SphereSet(self.bone[k], center, self.radius[k], self.radius_quantile)

    def to_bytes(self) -> bytes:
        """The ``.npz`` file content."""
        buf = io.BytesIO()
        meta = json.dumps({"format": FORMAT, "radius_quantile": float(self.radius_quantile)})
        np.savez(buf, meta=np.array(meta), bone=self.bone, a=self.a, b=self.b, radius=self.radius)
        return buf.getvalue()

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write an ``.npz`` atomically."""
        atomic_write_bytes(path, self.to_bytes())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CapsuleSet:
        """Read a file written by :meth:`save`."""
        data, meta = read_npz_with_meta(path, "capsule set")
        check(meta.get("format") == FORMAT, f"unsupported capsule set format {meta.get('format')!r}: {path}")
        return cls(data["bone"], data["a"], data["b"], data["radius"],
                   float(meta.get("radius_quantile", DEFAULT_RADIUS_QUANTILE)))


def _allot(counts: np.ndarray, total: int) -> np.ndarray:
    """``(J,)`` capsules per bone: 1 per bone with vertices, the rest by largest remainder of the vertex counts."""
    nz = counts > 0
    extra = (total - int(nz.sum())) * counts / counts.sum()
    alloc = nz.astype(np.int64) + np.floor(extra).astype(np.int64)
    left = total - int(alloc.sum())
    alloc[np.argsort(-(extra - np.floor(extra)), kind="stable")[:left]] += 1
    return alloc


def _piece(points: np.ndarray, radius_quantile: float, end_quantile: float,
           axis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """One capsule ``(a, b, r)`` of a piece's vertices (module doc; ``axis``: the bone's, else the piece's own)."""
    m = points.mean(0)
    x = points - m
    if points.shape[0] < 2:
        return m, m, 0.0
    u = np.linalg.svd(x, full_matrices=False)[2][0] if axis is None else axis
    t = x @ u
    r = float(np.quantile(np.linalg.norm(x - t[:, None] * u, axis=1), radius_quantile))
    t0, t1 = float(np.quantile(t, end_quantile)) + r, float(np.quantile(t, 1 - end_quantile)) - r
    if t1 < t0:
        t0 = t1 = 0.5 * (t0 + t1)
    return m + t0 * u, m + t1 * u, r


def fit_capsules(character: Any, n_capsules: int | None = None, seed: int = 0,
                 radius_quantile: float = DEFAULT_RADIUS_QUANTILE, end_quantile: float = DEFAULT_END_QUANTILE,
                 min_radius: float | None = None) -> CapsuleSet:
    """Fit bone-carried capsules to ``character``'s rest mesh (module doc for the rules).

    Args:
        character: a :class:`prt_torch.rig.character.Character` (``rest_vertices``, ``joints``, ``weights``).
        n_capsules: ``S``, at least the number of bones with vertices (``None``: exactly that, one per bone).
        seed: the k-means seed of the splits.
        radius_quantile: ``q`` in [0, 1] of the perpendicular distances (the radius).
        end_quantile: ``e`` in [0, 0.5) of the projections (the segment's ends).
        min_radius: floor on radii (default: 1e-3 of the rest mesh's bounding-box diagonal).
    """
    check(isinstance(radius_quantile, (int, float)) and 0.0 <= radius_quantile <= 1.0,
          f"radius_quantile must be in [0, 1], got {radius_quantile!r}")
    check(isinstance(end_quantile, (int, float)) and 0.0 <= end_quantile < 0.5,
          f"end_quantile must be in [0, 0.5), got {end_quantile!r}")
    verts = np.asarray(character.rest_vertices, dtype=np.float64)
    check_shape(verts, "V 3", name="rest vertices")
    check(verts.shape[0] >= 1 and bool(np.isfinite(verts).all()), "rest vertices must be finite (V >= 1, 3)")
    vb = vertex_bones(character.joints, character.weights)
    counts = np.bincount(vb, minlength=int(np.asarray(character.parents).size))
    n_bones = int((counts > 0).sum())
    n_capsules = n_bones if n_capsules is None else n_capsules
    check(isinstance(n_capsules, (int, np.integer)) and not isinstance(n_capsules, bool)
          and n_bones <= n_capsules <= verts.shape[0],
          f"capsule count must be an integer in [{n_bones}, {verts.shape[0]}] (bones with vertices .. vertices), "
          f"got {n_capsules!r}")
    if min_radius is None:
        min_radius = 1e-3 * float(np.linalg.norm(verts.max(0) - verts.min(0)))
    alloc = _allot(counts, int(n_capsules))
    bones, ends_a, ends_b, radii = [], [], [], []
    for j in np.flatnonzero(alloc):
        pts = verts[vb == j]
        k = int(alloc[j])
        if k > 1:  # split along the bone's principal axis (1-D k-means on the projections)
            x = pts - pts.mean(0)
            u = np.linalg.svd(x, full_matrices=False)[2][0]
            from sklearn.cluster import KMeans

            axis = u
            labels = KMeans(n_clusters=min(k, len(pts)), n_init=3, random_state=seed).fit((x @ u)[:, None]).labels_
        else:
            axis, labels = None, np.zeros(len(pts), np.int64)
        for c in np.unique(labels):
            a, b, r = _piece(pts[labels == c], radius_quantile, end_quantile, axis)
            bones.append(j)
            ends_a.append(a)
            ends_b.append(b)
            radii.append(r)
    r = np.maximum(np.asarray(radii), min_radius)
    return CapsuleSet(np.asarray(bones), np.asarray(ends_a), np.asarray(ends_b), r, float(radius_quantile))


def pose_capsules(capsules: CapsuleSet, skin_mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Posed endpoints ``a, b (..., S, 3)`` float32: ``skin_mats[..., bone] @ [a, 1]`` and the same of ``b``.

    Args:
        capsules: the set.
        skin_mats: ``(..., J, 4, 4)`` skinning matrices ``world_j @ inverse_bind_j`` (``Poses.skin``).
    """
    m = np.asarray(skin_mats)
    check_shape(m, "... J 4 4", name="skin matrices")
    check(int(capsules.bone.max()) < m.shape[-3],
          f"capsule bone {int(capsules.bone.max())} out of range for {m.shape[-3]} skin matrices")
    check(bool(np.isfinite(m).all()), "skin matrices contain NaN or Inf")
    mb = m[..., capsules.bone, :, :]  # (..., S, 4, 4)
    out = [np.einsum("...ij,...j->...i", mb[..., :3, :3], e.astype(np.float64)) + mb[..., :3, 3]
           for e in (capsules.a, capsules.b)]
    return out[0].astype(np.float32), out[1].astype(np.float32)


def posed_blockers(blockers: SphereSet | CapsuleSet, skin_mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Posed endpoints ``a, b (..., S, 3)`` float32 of either kind of blocker set: a :class:`CapsuleSet`'s
    (:func:`pose_capsules`), or a :class:`~prt_torch.blockers.spheres.SphereSet`'s centres twice (a sphere is a
    capsule with ``a == b``: :func:`prt_torch.blockers.cones.capsule_visibility_soa` treats it as the sphere)."""
    if isinstance(blockers, CapsuleSet):
        return pose_capsules(blockers, skin_mats)
    c = np.asarray(pose_spheres(blockers, skin_mats), dtype=np.float32)
    return c, c


def load_blocker_set(path: str | os.PathLike[str]) -> SphereSet | CapsuleSet:
    """A :class:`CapsuleSet` or a :class:`SphereSet` file (``peak_blockers.npz`` holds either), by its format."""
    from prt_torch.blockers.spheres import FORMAT as SPHERES

    meta = read_npz_with_meta(path, "blocker set")[1]
    check(meta.get("format") in (FORMAT, SPHERES), f"unsupported blocker set format {meta.get('format')!r}: {path}")
    return CapsuleSet.load(path) if meta["format"] == FORMAT else SphereSet.load(path)
