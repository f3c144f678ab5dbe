"""A game-style multi-mesh humanoid glTF written from the built-in character (independent of the loader under test).

:func:`write_game_humanoid` writes what exporters of game characters produce and the built-in names never show:

* joints renamed ``Skeleton_<name>_<k>`` (a prefix and a numbered suffix), so no name table matches them;
* the skin split over two mesh nodes: ``Body`` (skin 0, every joint, mesh space = glTF world) and ``Arms`` (skin 1,
  only the joints its vertices use, its own mesh space: a rotation + translation ``ARMS_SPACE`` folded into its
  inverse bind matrices);
* un-normalised weights: every vertex's weights scaled by a factor in ``[0.55, 1.45]`` (the same factor in both
  meshes, so seam vertices still weld);
* a rigid part: ``Helmet``, a box without a skin, child of the head joint node at ``HELMET_OFFSET``;
* a static prop that belongs to no skeleton: ``Crate``, a box at the scene root (the loader leaves it out);
* the built-in clips as LINEAR animations keyed at the character's fps.

The reference for tests is the built-in character itself (``make_character``): the loaded file must pose the same
vertices, plus the helmet carried rigidly by the head.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from prt_torch.rig.character import Character
from tests.rig.gltf_synth import GltfBuilder

#: z-up (the package's world) -> y-up glTF: the inverse of the loader's ``(x, y, z) -> (x, -z, y)``
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: the Arms mesh space -> glTF world
ARMS_SPACE = np.eye(4)
ARMS_SPACE[:3, :3] = Rotation.from_euler("xyz", [20.0, -35.0, 50.0], degrees=True).as_matrix()
ARMS_SPACE[:3, 3] = [0.3, -0.2, 0.7]
#: the helmet node's translation in the head joint's frame (file units), and the box's size
HELMET_OFFSET = (0.0, 0.0, 0.16)
HELMET_SIZE = (0.16, 0.2, 0.06)
#: the arm joints whose vertices make the Arms mesh
ARM_JOINTS = ("shoulder_l", "elbow_l", "wrist_l", "shoulder_r", "elbow_r", "wrist_r")


def renamed(name: str, k: int) -> str:
    """The file's name of built-in joint ``name`` (index ``k``)."""
    return f"Skeleton_{name}_{k + 1:02d}"


def _world(parents: np.ndarray, local: np.ndarray) -> np.ndarray:
    """``(..., J, 4, 4)`` world transforms of local ones (parents first)."""
    out = local.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            out[..., j, :, :] = out[..., p, :, :] @ local[..., j, :, :]
    return out


def _trs(m: np.ndarray) -> tuple[list[float], list[float]]:
    """Translation and ``xyzw`` quaternion of a rigid ``(4, 4)`` transform."""
    return m[:3, 3].tolist(), Rotation.from_matrix(m[:3, :3]).as_quat().tolist()


def write_game_humanoid(path: Path, c: Character, clips: tuple[str, ...] = ("walk", "wave", "squat"),
                        seed: int = 0) -> Path:
    """Write ``c`` (the built-in character, at its clips' fps) as the multi-mesh file described in the module
    docstring; ``clips`` the animations written. Returns ``path`` (``.glb`` or ``.gltf``)."""
    a4 = np.eye(4)
    a4[:3, :3] = Z_UP_TO_Y_UP
    J = c.num_joints
    world = a4[None] @ _world(c.parents, c.bind_local)  # glTF world rest transform of every joint
    b = GltfBuilder()
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.55, 1.45, c.num_vertices)
    weights = c.weights.astype(np.float64) * scale[:, None]
    dominant = c.joints[np.arange(c.num_vertices), np.argmax(c.weights, axis=1)]
    arm_ids = [c.joint_names.index(n) for n in ARM_JOINTS]
    in_arms = np.isin(dominant, arm_ids)[c.faces].all(axis=1)
    pos_world = c.rest_vertices.astype(np.float64) @ Z_UP_TO_Y_UP.T
    nrm_world = c.rest_normals.astype(np.float64) @ Z_UP_TO_Y_UP.T

    # joint nodes first: node k is joint k
    for j in range(J):
        local = world[j] if c.parents[j] < 0 else np.linalg.solve(world[c.parents[j]], world[j])
        t, r = _trs(local)
        kids = [int(k) for k in np.flatnonzero(c.parents == j)]
        b.node(name=renamed(c.joint_names[j], j), translation=t, rotation=r, **({"children": kids} if kids else {}))

    def mesh(faces: np.ndarray, space: np.ndarray, joint_list: list[int]) -> int:
        used = np.unique(faces)
        remap = np.full(c.num_vertices, -1, dtype=np.int64)
        remap[used] = np.arange(used.size)
        inv = np.linalg.inv(space)
        p = pos_world[used] @ inv[:3, :3].T + inv[:3, 3]
        n = nrm_world[used] @ space[:3, :3]  # inverse-transpose of inv(space) for row vectors
        local_index = {g: k for k, g in enumerate(joint_list)}
        jt = np.vectorize(lambda g: local_index.get(int(g), 0))(c.joints[used])
        wt = np.where(np.isin(c.joints[used], joint_list), weights[used], 0.0)
        k4 = max(4, jt.shape[1])
        jt = np.pad(jt, ((0, 0), (0, k4 - jt.shape[1])))[:, :4]
        wt = np.pad(wt, ((0, 0), (0, k4 - wt.shape[1])))[:, :4]
        b.doc["meshes"].append({"primitives": [{"attributes": {
            "POSITION": b.accessor(p.astype(np.float32)), "NORMAL": b.accessor(n.astype(np.float32)),
            "JOINTS_0": b.accessor(jt.astype(np.uint16)), "WEIGHTS_0": b.accessor(wt.astype(np.float32))},
            "indices": b.accessor(remap[faces].reshape(-1).astype(np.uint32)), "mode": 4}]})
        return len(b.doc["meshes"]) - 1

    def skin(joint_list: list[int], space: np.ndarray) -> int:
        ibm = np.linalg.inv(world[joint_list]) @ space[None]
        b.doc.setdefault("skins", []).append({"joints": joint_list, "inverseBindMatrices": b.accessor(
            ibm.transpose(0, 2, 1).reshape(-1, 16).astype(np.float32))})
        return len(b.doc["skins"]) - 1

    arm_joints = sorted({int(g) for g in np.unique(c.joints[np.unique(c.faces[in_arms])])})
    body = b.node(name="Body", mesh=mesh(c.faces[~in_arms], np.eye(4), list(range(J))), skin=skin(list(range(J)),
                                                                                                  np.eye(4)),
                  translation=[4.0, 0.0, 0.0])  # ignored: a skinned mesh node's own transform (spec)
    arms = b.node(name="Arms", mesh=mesh(c.faces[in_arms], ARMS_SPACE, arm_joints), skin=skin(arm_joints, ARMS_SPACE))
    box = trimesh.creation.box(extents=HELMET_SIZE)
    for name, parent, offset in (("Helmet", c.joint_names.index("head"), HELMET_OFFSET),
                                 ("Crate", None, (1.5, 0.2, 0.0))):
        b.doc["meshes"].append({"primitives": [{"attributes": {
            "POSITION": b.accessor(np.asarray(box.vertices, np.float32))},
            "indices": b.accessor(np.asarray(box.faces, np.uint32).reshape(-1)), "mode": 4}]})
        node = b.node(name=name, mesh=len(b.doc["meshes"]) - 1, translation=list(offset))
        if parent is None:
            b.doc["scenes"][0]["nodes"].append(node)
        else:
            b.doc["nodes"][parent].setdefault("children", []).append(node)
    b.doc["scenes"][0]["nodes"] += [int(np.flatnonzero(c.parents < 0)[0]), body, arms]

    anims = []
    for name in clips:
        clip = c.clips[name]
        local = clip.local.copy()
        roots = np.flatnonzero(c.parents < 0)
        local[:, roots] = a4 @ local[:, roots]
        times = b.accessor((np.arange(clip.num_frames) / clip.fps).astype(np.float32))
        samplers, channels = [], []
        for j in range(J):
            q = Rotation.from_matrix(local[:, j, :3, :3]).as_quat()
            for what, values in (("rotation", q), ("translation", local[:, j, :3, 3])):
                samplers.append({"input": times, "output": b.accessor(values.astype(np.float32)),
                                 "interpolation": "LINEAR"})
                channels.append({"sampler": len(samplers) - 1, "target": {"node": j, "path": what}})
        anims.append({"name": name, "samplers": samplers, "channels": channels})
    b.doc["animations"] = anims
    return b.write(path)


def helmet_rest(c: Character) -> np.ndarray:
    """``(8, 3)`` the helmet box's rest vertices in the package's z-up world (the reference for the rigid part)."""
    world = _world(c.parents, c.bind_local)[c.joint_names.index("head")]
    box = np.asarray(trimesh.creation.box(extents=HELMET_SIZE).vertices, dtype=np.float64)
    # world is z-up already (the A4 at the root and the loader's C cancel); the offset is in the head's frame
    return box @ world[:3, :3].T + world[:3, :3] @ np.asarray(HELMET_OFFSET) + world[:3, 3]
