"""A scene: several placed, animated characters and an optional ground plane (numpy only, no torch).

Placement. A character is placed by the rigid transform ``P = T(offset) Rz(yaw)`` applied to its skeleton's
root joint(s): ``local'[root] = P @ local[root]``. Forward kinematics then gives placed joints, LBS placed
vertices and normals, and the vertex-frame rule placed frames, with no other change anywhere; the pose
features exclude the root, so a character's learned visibility does not depend on where it stands. The
player (``Player.pose``) and the truth (:func:`pose_actor`, the bake's reference FK + LBS + vertex frames)
use the same placed locals.

Time. Scene frame ``i`` is at ``t = i / fps``; character ``k`` shows frame ``round((t + time_offset_k) *
fps_k) mod n_k`` of its clip (clips loop).

Overlap (``check_separated``): characters whose posed blocker spheres interpenetrate (centre distance below
the sum of radii, for any pair of spheres of two different characters) are refused with a one-line error
naming the characters and the frame: the cast-shadow composition assumes disjoint occluders (a receiver inside
another character's sphere is undefined, and the learned self-visibility knows nothing of a second body inside
it). Spheres fitted by :func:`prt_torch.blockers.fit_spheres` cover their vertices, so the check is
conservative: characters closer than their spheres' slack are refused too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.scene.config import GroundConfig
from prt_torch.scene.ground import Ground, make_ground

#: the radius of a blocker sphere wholly below the ground (:func:`spheres_above`): blocks nothing, stays > 0
MIN_RADIUS = 1e-6
#: ground margin beyond the characters' xy extent, in rest heights (``size: auto``)
GROUND_MARGIN_HEIGHTS = 1.5


def placement_matrix(offset: Any = (0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> np.ndarray:
    """``(4, 4)`` float64 ``T(offset) @ Rz(yaw)`` (yaw counter-clockwise seen from above, z up)."""
    a = np.radians(float(yaw_deg))
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = np.asarray(offset, dtype=np.float64).reshape(3)
    return m


@dataclass
class Actor:
    """One placed character of a scene.

    Attributes:
        character: the :class:`prt_torch.rig.Character`.
        clip: its :class:`prt_torch.rig.clip.Clip` (at the rate the scene plays it).
        placement: ``(4, 4)`` :func:`placement_matrix`.
        time_offset: seconds added to the scene time (the clip loops).
        cluster, cluster_axis, cluster_bone: the vertex-frame data of its run (``None``: no frames, e.g. a
            character that only occludes).
        spheres: its :class:`prt_torch.blockers.SphereSet` (``None`` until given).
        name: a label for messages.
    """

    character: Any
    clip: Any
    placement: np.ndarray = field(default_factory=lambda: np.eye(4))
    time_offset: float = 0.0
    cluster: np.ndarray | None = None
    cluster_axis: np.ndarray | None = None
    cluster_bone: np.ndarray | None = None
    spheres: Any = None
    name: str = "character"

    @property
    def roots(self) -> np.ndarray:
        return np.flatnonzero(np.asarray(self.character.parents) < 0)

    def frame_indices(self, scene_frames: np.ndarray, fps: float) -> np.ndarray:
        """Clip frame of each scene frame (looping; see the module docstring)."""
        n = int(np.asarray(self.clip.local).shape[0])
        t = np.asarray(scene_frames, dtype=np.float64) / float(fps) + self.time_offset
        return np.mod(np.rint(t * float(self.clip.fps)).astype(np.int64), n)

    def place(self, local: np.ndarray) -> np.ndarray:
        """``(F, J, 4, 4)`` locals with the placement applied to the root joint(s)."""
        out = np.array(local, dtype=np.float64, copy=True)
        out[:, self.roots] = self.placement @ out[:, self.roots]
        return out

    def locals(self, scene_frames: np.ndarray, fps: float) -> np.ndarray:
        """Placed ``(F, J, 4, 4)`` local joint transforms at the given scene frames."""
        return self.place(np.asarray(self.clip.local)[self.frame_indices(scene_frames, fps)])

    def rest_vertices(self) -> np.ndarray:
        """``(V, 3)`` float64 rest mesh, placed."""
        v = np.asarray(self.character.rest_vertices, dtype=np.float64)
        return v @ self.placement[:3, :3].T + self.placement[:3, 3]


@dataclass
class PosedMesh:
    """Posed characters (the reference path): ``positions (F, V, 3)`` float32, ``frames (F, V, 3, 3)`` float32
    (``None`` without frame data), ``skin (F, J, 4, 4)`` float64 placed skinning matrices."""

    positions: np.ndarray
    frames: np.ndarray | None
    skin: np.ndarray


def pose_actor(actor: Actor, placed_locals: np.ndarray) -> PosedMesh:
    """FK (:func:`prt_torch.rig.skeleton.forward_kinematics`), LBS (``Character.skin_mesh``) and the reference
    vertex frames (:func:`prt_torch.rig.vertex_frames.vertex_frames`) of placed locals ``(F, J, 4, 4)``."""
    from prt_torch.rig.skeleton import forward_kinematics
    from prt_torch.rig.vertex_frames import vertex_frames

    ch = actor.character
    skin = forward_kinematics(ch.parents, np.asarray(placed_locals, dtype=np.float64)) @ ch.inverse_bind[None]
    pos, nrm = ch.skin_mesh(skin)
    frames = None
    if actor.cluster is not None:
        frames = np.asarray(vertex_frames(nrm, skin, actor.cluster, actor.cluster_axis, actor.cluster_bone),
                            dtype=np.float32)
    return PosedMesh(np.asarray(pos, dtype=np.float32), frames, skin)


def check_separated(centers: list[np.ndarray], radii: list[np.ndarray], names: list[str] | None = None,
                    frame: int | str = 0) -> None:
    """One-line :class:`PrtError` if spheres of two different characters interpenetrate (module docstring).

    Args:
        centers: per character ``(S_k, 3)``; radii: per character ``(S_k,)``; names: labels; frame: for the
            message.
    """
    names = names or [f"character {k}" for k in range(len(centers))]
    for a in range(len(centers)):
        for b in range(a + 1, len(centers)):
            ca, cb = np.asarray(centers[a], np.float64), np.asarray(centers[b], np.float64)
            d = np.linalg.norm(ca[:, None] - cb[None], axis=-1)
            depth = (np.asarray(radii[a], np.float64)[:, None] + np.asarray(radii[b], np.float64)[None]) - d
            if depth.size and float(depth.max()) > 0.0:
                raise PrtError(f"scene: {names[a]} and {names[b]} overlap at frame {frame} (blocker spheres "
                               f"interpenetrate by {float(depth.max()):.3f} units): move them apart (offset)")


def scene_ground(cfg: GroundConfig, actors: list[Actor], fps: float | None = None,
                 n_frames: int | None = None) -> Ground:
    """The ground of ``cfg`` for placed ``actors`` (``size: auto`` / ``z: auto | clip``: :class:`GroundConfig`;
    ``z: clip`` poses ``n_frames`` scene frames at ``fps``)."""
    check(len(actors) > 0, "scene: a ground needs at least one character to place it")
    rest = [a.rest_vertices() for a in actors]
    lo = np.min([r.min(0) for r in rest], axis=0)
    hi = np.max([r.max(0) for r in rest], axis=0)
    height = float(max(r[:, 2].max() - r[:, 2].min() for r in rest))
    if cfg.z == "auto":
        z = float(lo[2])
    elif cfg.z == "clip":
        check(fps is not None and n_frames is not None, "ground z: clip needs the frames played")
        idx = np.arange(int(n_frames))
        z = min(float(pose_actor(Actor(a.character, a.clip, a.placement, a.time_offset), a.locals(idx, fps))
                      .positions[..., 2].min()) for a in actors)
    else:
        z = float(cfg.z)
    center = 0.5 * (lo[:2] + hi[:2])
    size = float(cfg.size) if cfg.size != "auto" else float((hi[:2] - lo[:2]).max() + 2 * GROUND_MARGIN_HEIGHTS
                                                            * height)
    return make_ground(center, size, z, cfg.resolution, cfg.albedo_rgb())


def spheres_above(centers: np.ndarray, radii: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Blocker spheres as the ground sees them: a sphere crossing the plane ``z = height`` is replaced by the
    sphere spanning its part above the plane (same xy, from the plane to its top: radius ``(top - height) / 2``),
    a sphere wholly below it shrinks to :data:`MIN_RADIUS` on the plane (it blocks nothing). The part of a bone's
    sphere below the floor is not there, and without this a foot's sphere sunk into the floor darkens a wide disc
    around the foot.

    Args:
        centers: ``(..., S, 3)``; radii: ``(..., S)`` (broadcast against ``centers[..., 0]``); height: the plane.

    Returns:
        ``(centers (..., S, 3), radii (..., S))`` float32.
    """
    c = np.array(centers, dtype=np.float32, copy=True)
    r = np.broadcast_to(np.asarray(radii, dtype=np.float32), c.shape[:-1]).copy()
    top = c[..., 2] + r
    cross = c[..., 2] - r < height
    new_r = np.maximum(0.5 * (top - height), MIN_RADIUS)
    r = np.where(cross, new_r, r)
    c[..., 2] = np.where(cross, height + new_r, c[..., 2])
    return c, r
