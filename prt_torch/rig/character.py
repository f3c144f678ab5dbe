"""The skinned character: skeleton, rest mesh, skin weights and clips (numpy only; no torch import).

Frames and units: z-up world (glTF/BVH y-up data is converted at the root with ``(x, y, z) -> (x, -z, y)``).
Skinning: linear blend skinning with ``skin_j = world_j @ inverse_bind_j``
(:mod:`prt_torch.rig.skinning`). Pose features: see :mod:`prt_torch.rig.features`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.exact import small_matmul
from prt_torch.io import atomic_path, read_npz_with_meta
from prt_torch.rig.clip import Clip
from prt_torch.rig.features import pose_features
from prt_torch.rig.material import Material
from prt_torch.rig.skeleton import check_parents, forward_kinematics
from prt_torch.rig.skinning import check_skin_weights, dense_weights, skin
from prt_torch.shapes import check_shape

FORMAT_VERSION = 1


@dataclass(repr=False)
class Poses:
    """One posed sequence of ``F`` frames.

    ``local``, ``world``, ``skin``: ``(F, J, 4, 4)`` float64 (``skin = world @ inverse_bind``);
    ``features``: ``(F, A)`` float32 pose features (root excluded); ``fps`` and the clip ``name``.
    """

    name: str
    fps: float
    local: np.ndarray
    world: np.ndarray
    skin: np.ndarray
    features: np.ndarray

    @property
    def num_frames(self) -> int:
        """``F``."""
        return int(self.local.shape[0])

    def __repr__(self) -> str:
        return f"Poses(name={self.name!r}, fps={self.fps}, F={self.num_frames}, A={self.features.shape[1]})"


@dataclass(repr=False)
class Character:
    """A skinned character. All arrays are numpy.

    * ``joint_names`` (J), ``parents (J,)`` int64 (-1 for roots, ``parents[j] < j``)
    * ``bind_local (J, 4, 4)`` float64 local joint transforms at the bind pose; ``inverse_bind (J, 4, 4)``
      float64 (``world_bind @ inverse_bind = I`` for a consistent rig)
    * ``rest_vertices (V, 3)`` float32 bind-pose positions in the z-up world, ``rest_normals (V, 3)`` unit
    * ``faces (T, 3)`` int64, welded, counter-clockwise seen from outside
    * ``joints (V, K)`` int64, ``weights (V, K)`` float32 (rows sum to 1)
    * ``clips``: name -> :class:`Clip`
    * ``joint_limits``: optional ``(J, 3, 2)`` radians, per joint ``[min, max]`` of the bind-relative
      angles ``(a_x, a_y, a_z)`` composed as ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` (used by
      :func:`prt_torch.rig.random_pose.random_poses`; ``None`` for loaded assets)
    * ``uv``: optional ``(T, 3, 2)`` float32 texture coordinates per triangle corner (glTF ``TEXCOORD_0``;
      per corner because welding merges vertices across UV seams)
    * ``material``: optional :class:`prt_torch.rig.material.Material` (base colour, roughness, metallic);
      ``None`` means :data:`prt_torch.rig.material.DEFAULT_MATERIAL`. Neither enters :meth:`content_hash`.
    """

    name: str
    joint_names: list[str]
    parents: np.ndarray
    bind_local: np.ndarray
    inverse_bind: np.ndarray
    rest_vertices: np.ndarray
    rest_normals: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    clips: dict[str, Clip] = field(default_factory=dict)
    joint_limits: np.ndarray | None = None
    uv: np.ndarray | None = None
    material: Material | None = None

    def __post_init__(self) -> None:
        self.parents = check_parents(self.parents)
        j = self.parents.size
        check(len(self.joint_names) == j, f"{len(self.joint_names)} joint names for {j} joints")
        self.joint_names = [str(n) for n in self.joint_names]
        for attr in ("bind_local", "inverse_bind"):
            a = np.asarray(getattr(self, attr), dtype=np.float64)
            check_shape(a, (j, 4, 4), name=attr)
            check(bool(np.all(np.isfinite(a))), f"{attr} contains NaN or inf")
            setattr(self, attr, a)
        v = np.asarray(self.rest_vertices)
        check_shape(v, "V 3", name="rest vertices")
        check(v.shape[0] > 0, f"rest vertices must be (V, 3), got {v.shape}")
        check(bool(np.all(np.isfinite(v))), "rest vertex positions contain NaN or inf")
        self.rest_vertices = v.astype(np.float32)
        n = np.asarray(self.rest_normals)
        check_shape(n, v.shape, name="rest normals")
        check(bool(np.all(np.isfinite(n))), "rest normals contain NaN or inf")
        self.rest_normals = n.astype(np.float32)
        f = np.asarray(self.faces)
        check_shape(f, "T 3", name="faces")
        check(np.issubdtype(f.dtype, np.integer), f"faces must be (T, 3) integers, got {f.shape} {f.dtype}")
        check(bool(np.all((f >= 0) & (f < v.shape[0]))), f"face indices must lie in [0, {v.shape[0]})")
        self.faces = f.astype(np.int64)
        self.joints, self.weights = check_skin_weights(self.joints, self.weights, j, v.shape[0])
        for name, clip in self.clips.items():
            check(clip.num_joints == j, f"clip {name!r} has {clip.num_joints} joints, the skeleton {j}")
        if self.joint_limits is not None:
            lim = np.asarray(self.joint_limits, dtype=np.float64)
            check_shape(lim, (j, 3, 2), name="joint limits")
            check(bool(np.all(lim[..., 0] <= lim[..., 1])), "joint limits must have min <= max")
            self.joint_limits = lim
        if self.uv is not None:
            uv = np.asarray(self.uv, dtype=np.float32)
            check_shape(uv, (len(self.faces), 3, 2), name="uv")
            check(bool(np.all(np.isfinite(uv))), "uv contains NaN or inf")
            self.uv = uv
        check(self.material is None or isinstance(self.material, Material),
              f"material must be a Material, got {type(self.material).__name__}")
        self._dense_w: np.ndarray | None = None
        self._dense_wt: np.ndarray | None = None

    def __repr__(self) -> str:
        return (f"Character(name={self.name!r}, V={self.num_vertices}, T={len(self.faces)}, J={self.num_joints}, "
                f"clips={list(self.clips)})")

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def num_joints(self) -> int:
        """``J``."""
        return int(self.parents.size)

    @property
    def num_vertices(self) -> int:
        """``V``."""
        return int(self.rest_vertices.shape[0])

    @property
    def feature_width(self) -> int:
        """``A = 6 * (number of non-root joints)``."""
        return 6 * int(np.sum(self.parents >= 0))

    @property
    def dense_weights(self) -> np.ndarray:
        """``(V, J)`` float32 dense skin weights (cached)."""
        if self._dense_w is None:
            self._dense_w = dense_weights(self.joints, self.weights, self.num_joints)
            self._dense_wt = np.ascontiguousarray(self._dense_w.T)
        return self._dense_w

    # -- posing --------------------------------------------------------------------------------
    def clip(self, clip: str | Clip) -> Clip:
        """Look up a clip by name (or pass a :class:`Clip` through, checking its joint count)."""
        if isinstance(clip, Clip):
            check(clip.num_joints == self.num_joints,
                  f"clip {clip.name!r} has {clip.num_joints} joints, the character {self.num_joints}")
            return clip
        if clip not in self.clips:
            raise PrtError(f"unknown clip {clip!r} for character {self.name!r}; available: {sorted(self.clips)}")
        return self.clips[clip]

    def bind_clip(self) -> Clip:
        """A one-frame clip holding the bind pose."""
        return Clip("bind", 30.0, self.bind_local[None].copy())

    def pose(self, clip: str | Clip, fps: float | None = None) -> Poses:
        """Pose a clip (name or :class:`Clip`), resampled at ``fps`` when given -> :class:`Poses`."""
        c = self.clip(clip)
        if fps is not None and fps != c.fps:
            c = c.resample(fps)
        world = forward_kinematics(self.parents, c.local)
        skin_mats = small_matmul(world, self.inverse_bind[None])  # fixed order: the bake is bit-exact
        feats = pose_features(c.local, self.bind_local, self.parents)
        return Poses(c.name, c.fps, c.local, world, skin_mats, feats)

    def skin_mesh(self, poses: Poses | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Skinned ``positions (F, V, 3)`` and unit ``normals (F, V, 3)`` float32 (z-up world).

        ``poses``: a :class:`Poses` or skin matrices ``(F, J, 4, 4)`` / ``(J, 4, 4)`` (then no F axis).
        """
        mats = poses.skin if isinstance(poses, Poses) else np.asarray(poses)
        pos, nrm = skin(mats, self.dense_weights, self.rest_vertices, self.rest_normals, self._dense_wt)
        assert nrm is not None
        return pos, nrm

    def scaled(self, factor: float) -> Character:
        """The same character uniformly scaled by ``factor`` about the world origin (clips included).

        Every transform ``M`` becomes ``S M S^-1`` (``S = diag(f, f, f, 1)``: translations scale, rotations
        do not), rest vertices scale, normals are unchanged; skinning commutes with the scaling.
        """
        check(bool(np.isfinite(factor)) and factor > 0, f"scale factor must be > 0, got {factor}")
        s = np.diag([factor, factor, factor, 1.0])
        s_inv = np.diag([1.0 / factor] * 3 + [1.0])
        clips = {n: Clip(c.name, c.fps, s @ c.local @ s_inv) for n, c in self.clips.items()}
        return Character(self.name, list(self.joint_names), self.parents.copy(), s @ self.bind_local @ s_inv,
                         s @ self.inverse_bind @ s_inv, self.rest_vertices * np.float32(factor),
                         self.rest_normals.copy(), self.faces.copy(), self.joints.copy(), self.weights.copy(), clips,
                         None if self.joint_limits is None else self.joint_limits.copy(),
                         None if self.uv is None else self.uv.copy(), self.material)

    # -- identity & persistence ----------------------------------------------------------------
    def content_hash(self) -> str:
        """sha256 (hex) of geometry, skeleton and skin weights (not the clips or the name)."""
        h = hashlib.sha256()
        h.update(json.dumps(self.joint_names).encode())
        for a, dt in ((self.parents, np.int64), (self.bind_local, np.float64), (self.inverse_bind, np.float64),
                      (self.rest_vertices, np.float32), (self.rest_normals, np.float32), (self.faces, np.int64),
                      (self.joints, np.int64), (self.weights, np.float32)):
            arr = np.ascontiguousarray(a, dtype=dt)
            h.update(str(arr.shape).encode())
            h.update(arr.tobytes())
        return h.hexdigest()

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write everything (incl. clips and joint limits) to one ``.npz`` atomically."""
        names = list(self.clips)
        arrays: dict[str, np.ndarray] = {
            "meta": np.array(json.dumps({"format": FORMAT_VERSION, "name": self.name, "joint_names": self.joint_names,
                                         "clips": names, "fps": [self.clips[n].fps for n in names]})),
            "parents": self.parents, "bind_local": self.bind_local, "inverse_bind": self.inverse_bind,
            "rest_vertices": self.rest_vertices, "rest_normals": self.rest_normals, "faces": self.faces,
            "joints": self.joints, "weights": self.weights,
        }
        if self.joint_limits is not None:
            arrays["joint_limits"] = self.joint_limits
        if self.uv is not None:  # optional keys: files without them still load (no material, no UVs)
            arrays["uv"] = self.uv
        if self.material is not None:
            arrays["material"] = np.array(self.material.to_json())
            if self.material.texture is not None:
                arrays["material_texture"] = self.material.texture
        for i, n in enumerate(names):
            arrays[f"clip_{i}"] = self.clips[n].local
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                f.write(buf.getvalue())
                f.flush()
                os.fsync(f.fileno())

    @staticmethod
    def load_skinning(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Only the skinning of a file written by :meth:`save`: ``parents (J,)``, ``joints (V, K)``,
        ``weights (V, K)`` (what per-cluster joint input selection needs, without the clips)."""
        path = Path(path)
        if not path.is_file():
            raise PrtError(f"the skinning of the character is needed: {path} not found")
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in ("parents", "joints", "weights") if k not in z.files]
                check(not missing, f"{path}: no {', '.join(missing)} array")
                return np.asarray(z["parents"]), np.asarray(z["joints"]), np.asarray(z["weights"])
        except (OSError, ValueError) as e:
            raise PrtError(f"not a character .npz file: {path} ({type(e).__name__})") from None

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Character:
        """Read a character written by :meth:`save`."""
        data, meta = read_npz_with_meta(path, "character")
        check(meta.get("format") == FORMAT_VERSION, f"unsupported character file format {meta.get('format')}: {path}")
        clips = {n: Clip(n, fps, data[f"clip_{i}"]) for i, (n, fps) in enumerate(zip(meta["clips"], meta["fps"],
                                                                                       strict=True))}
        return cls(meta["name"], meta["joint_names"], data["parents"], data["bind_local"], data["inverse_bind"],
                   data["rest_vertices"], data["rest_normals"], data["faces"], data["joints"], data["weights"],
                   clips, data.get("joint_limits"), data.get("uv"),
                   Material.from_json(str(data["material"]), data.get("material_texture"))
                   if "material" in data else None)
