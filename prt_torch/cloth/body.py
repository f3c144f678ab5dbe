"""The cape's body: kinematic capsule colliders along the bones, the cape's rest shape and its anchor row.

Conventions: z-up world, the character faces -y (the glTF/BVH conversion of :mod:`prt_torch.rig` and the
built-in humanoid), so the cape hangs on the +y side. Everything is fitted once on the bind pose and carried
rigidly by a joint's skin matrix ``skin_j = world_j @ inverse_bind_j`` (:attr:`prt_torch.rig.character.Poses.skin`),
like :mod:`prt_torch.blockers` carries its spheres.

Capsules (:func:`fit_capsules`): every vertex belongs to the joint of its largest skin weight; a joint's
vertices are split between the bone segments from the joint to each of its children (a leaf joint: from the
joint through its vertices' centroid), each vertex going to its nearest segment; a segment's radius is the
``quantile`` of its vertices' distances to it (a robust radius of the limb around the bone).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rig.skeleton import forward_kinematics

#: radius quantile of a capsule's vertices (0.5: the median limb radius; the torso is wider than deep)
CAPSULE_QUANTILE = 0.6
#: fewest vertices a capsule is fitted to
MIN_CAPSULE_VERTICES = 8


@dataclass
class Capsules:
    """Capsule colliders in the bind pose: ``joint (C,)`` int64 carrying joint, segment ends ``a``, ``b``
    ``(C, 3)`` float64 (world, bind pose) and ``radius (C,)`` float64 metres."""

    joint: np.ndarray
    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray

    def __len__(self) -> int:
        return int(self.joint.size)

    def posed(self, skin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment ends ``(a, b)`` ``(..., C, 3)`` carried by skin matrices ``(..., J, 4, 4)``."""
        m = np.asarray(skin)[..., self.joint, :, :]
        a = np.einsum("...cij,cj->...ci", m[..., :3, :3], self.a) + m[..., :3, 3]
        b = np.einsum("...cij,cj->...ci", m[..., :3, :3], self.b) + m[..., :3, 3]
        return a, b


def capsule_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Signed distance ``(..., N)`` of ``points (..., N, 3)`` to the union of capsules ``a, b (..., C, 3)``,
    ``radius (C,)`` (negative inside)."""
    p = np.asarray(points, dtype=np.float64)[..., :, None, :]  # (..., N, 1, 3)
    a = np.asarray(a, dtype=np.float64)[..., None, :, :]
    ab = np.asarray(b, dtype=np.float64)[..., None, :, :] - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-18), 0.0, 1.0)
    d = np.linalg.norm(p - (a + t[..., None] * ab), axis=-1) - np.asarray(radius)
    return d.min(axis=-1)


def bind_joint_positions(character: Character) -> np.ndarray:
    """``(J, 3)`` world joint positions of the bind pose."""
    return forward_kinematics(character.parents, character.bind_local[None])[0, :, :3, 3]


def fit_capsules(character: Character, quantile: float = CAPSULE_QUANTILE) -> Capsules:
    """Capsules along the bones of ``character`` (module docstring); deterministic."""
    rest = character.rest_vertices.astype(np.float64)
    owner = character.joints[np.arange(character.num_vertices), np.argmax(character.weights, axis=1)]
    jpos = bind_joint_positions(character)
    joints, aa, bb, rr = [], [], [], []
    for j in range(character.num_joints):
        pts = rest[owner == j]
        if len(pts) < MIN_CAPSULE_VERTICES:
            continue
        children = np.flatnonzero(character.parents == j)
        if children.size:
            ends = jpos[children]
        else:
            ends = (pts.mean(axis=0) + 0.5 * (pts.mean(axis=0) - jpos[j]))[None]
        a = np.repeat(jpos[j][None], len(ends), axis=0)
        keep = np.linalg.norm(ends - a, axis=1) > 1e-6
        a, ends = a[keep], ends[keep]
        if not len(a):
            continue
        dist = np.stack([capsule_distance(pts, a[i:i + 1], ends[i:i + 1], np.zeros(1)) for i in range(len(a))], 1)
        nearest = np.argmin(dist, axis=1)
        for i in range(len(a)):
            d = dist[nearest == i, i]
            if d.size >= MIN_CAPSULE_VERTICES:
                joints.append(j)
                aa.append(a[i])
                bb.append(ends[i])
                rr.append(float(np.quantile(d, quantile)))
    if not joints:
        raise PrtError(f"character {character.name!r}: no bone has {MIN_CAPSULE_VERTICES} vertices to fit a collider")
    return Capsules(np.asarray(joints, np.int64), np.asarray(aa), np.asarray(bb), np.asarray(rr))


def anchor_joint(character: Character) -> int:
    """The joint the cape's top row is fixed to: the lowest common ancestor of the shoulder/clavicle joints
    (the chest of a humanoid); without such joints, the root."""
    names = [i for i, n in enumerate(character.joint_names) if any(k in n.lower() for k in ("clavicle", "shoulder"))]
    if not names:
        return int(np.flatnonzero(character.parents < 0)[0])

    def chain(j: int) -> list[int]:
        out = [j]
        while character.parents[out[-1]] >= 0:
            out.append(int(character.parents[out[-1]]))
        return out

    common = set(chain(names[0]))
    for j in names[1:]:
        common &= set(chain(j))
    return max(common) if common else int(np.flatnonzero(character.parents < 0)[0])


def cape_rest(character: Character, capsules: Capsules, rows: int, cols: int, width: float, height: float,
              clearance: float) -> np.ndarray:
    """``(rows * cols, 3)`` float64 rest vertices of the cape, row-major (row 0 = the top, pinned row).

    Row ``r`` is a horizontal line at ``z = z_top - r * height / (rows - 1)`` (``z_top``: the shoulders'
    height), ``x`` across ``[-width/2, width/2]``, set back (+y) just far enough that every vertex of the row
    clears every capsule by ``clearance``; going down, a row is never closer to the body than the row above
    (the cape drapes from the shoulders).
    """
    jpos = bind_joint_positions(character)
    sh = [i for i, n in enumerate(character.joint_names) if any(k in n.lower() for k in ("clavicle", "shoulder"))]
    z_top = float(jpos[sh, 2].mean()) if sh else float(0.8 * character.rest_vertices[:, 2].max())
    x = np.linspace(-width / 2, width / 2, cols)
    z = z_top - np.linspace(0.0, height, rows)
    xz = np.stack(np.broadcast_arrays(x[None, :], z[:, None]), -1).reshape(-1, 2)  # (rows * cols, 2)

    def blocked(y: np.ndarray) -> np.ndarray:
        pts = np.column_stack([xz[:, 0], y, xz[:, 1]])
        return capsule_distance(pts, capsules.a, capsules.b, capsules.radius) <= clearance

    # the last blocked y of a coarse scan (the cloth must clear everything behind it), then bisection
    lo_all = float(capsules.a[:, 1].min() - capsules.radius.max())
    step = 0.02
    grid = lo_all + step * np.arange(int((capsules.b[:, 1].max() + capsules.radius.max() + clearance - lo_all)
                                         / step) + 2)
    last = np.full(len(xz), np.nan)
    for y in grid:
        last = np.where(blocked(np.full(len(xz), y)), y, last)
    lo = np.where(np.isnan(last), lo_all, last)
    hi = lo + step
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        b = blocked(mid)
        lo, hi = np.where(b, mid, lo), np.where(b, hi, mid)
    y_row = np.maximum.accumulate(hi.reshape(rows, cols).max(axis=1))
    g = np.stack(np.broadcast_arrays(x[None, :], y_row[:, None], z[:, None]), -1)
    return g.reshape(-1, 3)
