"""glTF 2.0 skinned characters -> :class:`~prt_torch.rig.character.Character` (pygltflib + numpy).

What is read:

* the default scene's node hierarchy; the skin of the first skinned mesh node and every mesh node
  using that skin (all their triangle primitives are merged);
* ``POSITION``, ``NORMAL`` (optional), ``JOINTS_0/WEIGHTS_0`` (+ ``JOINTS_1/WEIGHTS_1``), indices;
  normalised integer attributes, strided buffer views, sparse accessors; ``.glb``, ``.gltf`` with
  data-URI or external buffers;
* inverse bind matrices; per the spec the skinned mesh node's own transform is ignored;
* animations sampled at a chosen fps with ``STEP``, ``LINEAR`` (quaternion slerp) and
  ``CUBICSPLINE`` (Hermite with in/out tangents, quaternions renormalised) samplers; an animation
  becomes a clip when at least one of its channels targets a joint of the skin.

Clip names (:func:`clip_names`; ``prt info FILE`` lists them): a named animation keeps its ``name``
verbatim; an unnamed one (no ``name``, or an empty one) is ``animation_<i>``, ``i`` its 0-based index
in the file's ``animations`` array (skipped animations count, so the name does not depend on the
others). Where several clips end up with the same name, the first in file order keeps it and each
later one becomes ``<name>_<k>``, ``k = 2, 3, ...`` the smallest number giving a name that no clip of
the file has; a name that occurs once is never changed.

Conventions: the y-up glTF world is converted to z-up by ``C: (x, y, z) -> (x, -z, y)`` applied at
the root. The skeleton keeps only the skin's joints (sorted so parents come first); static
non-joint nodes between a joint and its nearest joint ancestor (or the scene root, incl. e.g. a
``Z_UP`` matrix node) are folded into the joint's local transform (``local = prefix @ TRS(t)``);
animation of non-joint nodes is ignored. Bind pose: with ``G = world_rest(root joint) @ IBM_root``
(mesh space -> glTF world; the same for every joint of a rig bound at its rest pose),
``world_bind_j = C G inv(IBM_j)``, ``inverse_bind_j = IBM_j inv(C G)``, ``rest_vertices = C G @ mesh
positions``, so skinning reproduces the glTF result (rotated to z-up) exactly at every pose. Units are
the file's (Fox.glb is ~80 units tall). Vertices are welded on equal position and skin
(non-indexed files such as Fox.glb); missing normals are computed (area weighted), existing ones
are averaged over welded duplicates. Weights within ``WEIGHT_TOLERANCE`` of summing to one are
renormalised; others raise :class:`~prt_torch.errors.PrtError`.
"""

from __future__ import annotations

import base64
import os
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.mesh import vertex_normals, weld
from prt_torch.rig.rotations import Y_UP_TO_Z_UP, matrix_to_quat, quat_to_matrix, slerp, trs_matrix

WEIGHT_TOLERANCE = 0.02

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_C4 = np.eye(4)
_C4[:3, :3] = Y_UP_TO_Z_UP


class _Reader:
    """Accessor data of one glTF document as numpy arrays."""

    def __init__(self, gltf, path: Path) -> None:  # gltf: pygltflib.GLTF2
        self.gltf = gltf
        self.path = path
        self._buffers: dict[int, bytes] = {}

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            buf = self.gltf.buffers[i]
            uri = buf.uri
            if uri is None:
                data = self.gltf.binary_blob()
                check(data is not None, f"{self.path.name}: buffer {i} has no data (no GLB binary chunk)")
            elif uri.startswith("data:"):
                data = base64.b64decode(uri.split(",", 1)[1])
            else:
                f = self.path.parent / uri
                check(f.is_file(), f"{self.path.name}: external buffer not found: {f}")
                data = f.read_bytes()
            check(len(data) >= buf.byteLength, f"{self.path.name}: buffer {i} is shorter than its byteLength")
            self._buffers[i] = data
        return self._buffers[i]

    def _view(self, view_index: int, offset: int, dtype: np.dtype, count: int, ncomp: int) -> np.ndarray:
        view = self.gltf.bufferViews[view_index]
        data = self.buffer(view.buffer)
        start = (view.byteOffset or 0) + offset
        item = np.dtype(dtype).itemsize * ncomp
        stride = view.byteStride or item
        end = start + stride * (count - 1) + item if count else start
        check(end <= len(data), f"{self.path.name}: accessor reads past the end of its buffer")
        raw = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
        if stride == item:
            return np.frombuffer(raw.tobytes(), dtype=dtype).reshape(count, ncomp)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1))
        return np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype).reshape(count, ncomp)

    def read(self, accessor_index: int) -> np.ndarray:
        """Accessor -> ``(count, ncomp)`` array (float64 for normalised/float data, int64 otherwise)."""
        check(0 <= accessor_index < len(self.gltf.accessors), f"{self.path.name}: bad accessor {accessor_index}")
        acc = self.gltf.accessors[accessor_index]
        check(acc.componentType in _COMPONENT, f"{self.path.name}: unsupported componentType {acc.componentType}")
        check(acc.type in _NCOMP, f"{self.path.name}: unsupported accessor type {acc.type}")
        dtype, ncomp = np.dtype(_COMPONENT[acc.componentType]), _NCOMP[acc.type]
        if acc.bufferView is None:
            out = np.zeros((acc.count, ncomp), dtype=dtype)
        else:
            out = self._view(acc.bufferView, acc.byteOffset or 0, dtype, acc.count, ncomp).copy()
        if acc.sparse is not None and acc.sparse.count:
            sp = acc.sparse
            idx = self._view(sp.indices.bufferView, sp.indices.byteOffset or 0,
                             np.dtype(_COMPONENT[sp.indices.componentType]), sp.count, 1)[:, 0].astype(np.int64)
            out[idx] = self._view(sp.values.bufferView, sp.values.byteOffset or 0, dtype, sp.count, ncomp)
        if np.issubdtype(dtype, np.floating):
            return out.astype(np.float64)
        if acc.normalized:
            info = np.iinfo(dtype)
            return np.maximum(out.astype(np.float64) / info.max, -1.0)
        return out.astype(np.int64)


def _node_matrix(node) -> np.ndarray:
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
    return trs_matrix(node.translation, node.rotation, node.scale)


def _node_trs(node) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if node.matrix is not None:
        m = _node_matrix(node)
        s = np.linalg.norm(m[:3, :3], axis=0)
        return m[:3, 3].copy(), matrix_to_quat(m[:3, :3] / s), s
    t = np.zeros(3) if node.translation is None else np.asarray(node.translation, dtype=np.float64)
    r = np.array([0.0, 0.0, 0.0, 1.0]) if node.rotation is None else np.asarray(node.rotation, dtype=np.float64)
    s = np.ones(3) if node.scale is None else np.asarray(node.scale, dtype=np.float64)
    return t, r, s


def _sample(times: np.ndarray, values: np.ndarray, interp: str, t: np.ndarray, is_quat: bool) -> np.ndarray:
    """Evaluate one sampler at times ``t (n,)``: ``times (k,)``, ``values (k, c)`` or ``(3k, c)`` for cubic."""
    k = times.size
    if interp == "CUBICSPLINE":
        check(values.shape[0] == 3 * k, "CUBICSPLINE sampler output must hold 3 values (in, value, out) per key")
        a, v, b = values[0::3], values[1::3], values[2::3]
    else:
        v = values
        check(v.shape[0] == k, f"{interp} sampler has {k} times but {v.shape[0]} values")
    if k == 1:
        out = np.repeat(v[:1], t.size, axis=0)
        return out / np.linalg.norm(out, axis=-1, keepdims=True) if is_quat else out
    te = t + 1e-6 * np.maximum(1.0, np.abs(t))  # key times are float32: a frame "on" a key reaches it
    i = np.clip(np.searchsorted(times, te, side="right") - 1, 0, k - 2)
    td = times[i + 1] - times[i]
    s = np.clip((t - times[i]) / np.where(td > 0, td, 1.0), 0.0, 1.0)
    if interp == "STEP":
        out = np.where((te >= times[i + 1])[:, None], v[i + 1], v[i])
    elif interp == "CUBICSPLINE":
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        out = (h00[:, None] * v[i] + (h10 * td)[:, None] * b[i] + h01[:, None] * v[i + 1]
               + (h11 * td)[:, None] * a[i + 1])
    elif interp == "LINEAR":
        out = slerp(v[i], v[i + 1], s) if is_quat else v[i] + (v[i + 1] - v[i]) * s[:, None]
    else:
        raise PrtError(f"unknown glTF animation interpolation {interp!r}")
    if is_quat:
        out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return out


def clip_names(animations: list[tuple[int, str | None]]) -> list[str]:
    """Clip names of glTF animations ``(index in the file's animations array, name or None)``, in file order.

    The module docstring states the rule: ``name`` verbatim, else ``animation_<index>``; the later of
    equal names become ``<name>_<k>`` with the smallest ``k >= 2`` not taken by any clip name.
    """
    base = [name if name else f"animation_{index}" for index, name in animations]
    taken = set(base)
    out: list[str] = []
    used: set[str] = set()
    for name in base:
        if name in used:
            k = 2
            while f"{name}_{k}" in taken:
                k += 1
            name = f"{name}_{k}"
            taken.add(name)
        used.add(name)
        out.append(name)
    return out


def load_gltf(path: str | os.PathLike[str], fps: float = 30.0, name: str | None = None,
              height: float | None = None) -> Character:
    """Load a skinned glTF 2.0 character (``.glb`` or ``.gltf``) with its animations sampled at ``fps``.

    ``height``: if given, the character is uniformly scaled (:meth:`Character.scaled`) so that its rest
    mesh spans ``height`` units along z (e.g. ``1.8`` for Fox.glb, which is ~80 units tall in the file).
    """
    import pygltflib

    path = Path(path)
    check(path.is_file(), f"glTF file not found: {path}")
    check(path.suffix.lower() in (".glb", ".gltf"), f"unknown character file format {path.suffix!r}: {path.name}")
    check(bool(np.isfinite(fps)) and fps > 0, f"fps must be > 0, got {fps}")
    try:
        gltf = pygltflib.GLTF2().load(str(path))
    except Exception as e:  # pygltflib raises assorted errors on malformed files
        raise PrtError(f"cannot parse glTF file {path.name}: {type(e).__name__}") from None
    check(gltf is not None and len(gltf.nodes) > 0, f"glTF file {path.name} has no nodes")
    reader = _Reader(gltf, path)
    nodes = gltf.nodes
    parent = -np.ones(len(nodes), dtype=np.int64)
    for i, n in enumerate(nodes):
        for c in n.children or []:
            parent[c] = i
    skinned = [i for i, n in enumerate(nodes) if n.mesh is not None and n.skin is not None]
    check(len(skinned) > 0, f"glTF file {path.name} has no skinned mesh (no node with both a mesh and a skin)")
    skin_index = nodes[skinned[0]].skin
    skin = gltf.skins[skin_index]
    mesh_nodes = [i for i in skinned if nodes[i].skin == skin_index]
    joint_nodes = list(skin.joints)
    check(len(joint_nodes) > 0, f"glTF skin {skin_index} of {path.name} has no joints")
    joint_set = set(joint_nodes)

    def depth(i: int) -> int:
        d = 0
        while parent[i] >= 0:
            i, d = int(parent[i]), d + 1
        return d

    order = sorted(range(len(joint_nodes)), key=lambda k: (depth(joint_nodes[k]), k))  # parents first
    old_to_new = np.empty(len(joint_nodes), dtype=np.int64)
    old_to_new[order] = np.arange(len(order))
    jnodes = [joint_nodes[k] for k in order]
    node_to_joint = {n: j for j, n in enumerate(jnodes)}
    parents = np.empty(len(jnodes), dtype=np.int64)
    prefix = np.empty((len(jnodes), 4, 4))
    for j, n in enumerate(jnodes):
        m = np.eye(4)
        a = int(parent[n])
        while a >= 0 and a not in joint_set:
            m = _node_matrix(nodes[a]) @ m
            a = int(parent[a])
        parents[j] = node_to_joint[a] if a >= 0 else -1
        prefix[j] = m if a >= 0 else _C4 @ m

    if skin.inverseBindMatrices is not None:
        ibm = reader.read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        check(ibm.shape[0] == len(joint_nodes), f"{path.name}: {ibm.shape[0]} inverse bind matrices for "
                                                 f"{len(joint_nodes)} joints")
    else:
        ibm = np.tile(np.eye(4), (len(joint_nodes), 1, 1))
    ibm = ibm[order]
    check(bool(np.all(np.isfinite(ibm))), f"{path.name}: inverse bind matrices contain NaN or inf")
    # mesh space -> glTF world at the node rest pose; exact posing holds for any invertible G, and
    # for a rig bound at its rest pose G is the same for every joint (the bind pose is the rest pose)
    node_world = np.empty((len(nodes), 4, 4))
    for i in sorted(range(len(nodes)), key=depth):
        node_world[i] = _node_matrix(nodes[i]) if parent[i] < 0 else node_world[parent[i]] @ _node_matrix(nodes[i])
    g = node_world[jnodes[0]] @ ibm[0]
    check(abs(np.linalg.det(g[:3, :3])) > 1e-12, f"{path.name}: singular bind transform")
    cg = _C4 @ g
    bind_world = cg[None] @ np.linalg.inv(ibm)
    inverse_bind = ibm @ np.linalg.inv(cg)[None]
    bind_local = bind_world.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            bind_local[j] = np.linalg.solve(bind_world[p], bind_world[j])

    # -- geometry ---------------------------------------------------------------------------------
    pos_l, nrm_l, jnt_l, wgt_l, face_l = [], [], [], [], []
    have_normals = True
    offset = 0
    for mi in mesh_nodes:
        for prim in gltf.meshes[nodes[mi].mesh].primitives:
            if prim.mode not in (None, 4):
                continue  # points/lines/strips are not surfaces we can shade
            at = prim.attributes
            check(at.POSITION is not None, f"{path.name}: a primitive has no POSITION")
            check(at.JOINTS_0 is not None and at.WEIGHTS_0 is not None,
                  f"{path.name}: a skinned primitive has no JOINTS_0/WEIGHTS_0")
            p = reader.read(at.POSITION)
            jt = reader.read(at.JOINTS_0)
            wt = reader.read(at.WEIGHTS_0).astype(np.float64)
            if getattr(at, "JOINTS_1", None) is not None and getattr(at, "WEIGHTS_1", None) is not None:
                jt = np.concatenate([jt, reader.read(at.JOINTS_1)], axis=1)
                wt = np.concatenate([wt, reader.read(at.WEIGHTS_1).astype(np.float64)], axis=1)
            if at.NORMAL is not None:
                nrm_l.append(reader.read(at.NORMAL))
            else:
                have_normals = False
            idx = (np.arange(p.shape[0]) if prim.indices is None else reader.read(prim.indices)[:, 0])
            check(idx.size % 3 == 0, f"{path.name}: triangle primitive index count is not a multiple of 3")
            pos_l.append(p)
            jnt_l.append(jt)
            wgt_l.append(wt)
            face_l.append(idx.reshape(-1, 3) + offset)
            offset += p.shape[0]
    check(len(pos_l) > 0, f"{path.name}: the skinned mesh has no triangle primitives")
    k = max(j.shape[1] for j in jnt_l)
    jnt = np.concatenate([np.pad(j, ((0, 0), (0, k - j.shape[1]))) for j in jnt_l])
    wgt = np.concatenate([np.pad(w, ((0, 0), (0, k - w.shape[1]))) for w in wgt_l])
    pos = np.concatenate(pos_l)
    faces = np.concatenate(face_l)
    check(bool(np.all(np.isfinite(pos))), f"{path.name}: vertex positions contain NaN or inf")
    check(bool(np.all(np.isfinite(wgt))), f"{path.name}: skin weights contain NaN or inf")
    check(bool(np.all((faces >= 0) & (faces < pos.shape[0]))), f"{path.name}: triangle indices out of range")
    check(bool(np.all((jnt >= 0) & (jnt < len(joint_nodes)))), f"{path.name}: JOINTS_0 index out of range")
    sums = wgt.sum(axis=1)
    bad = np.abs(sums - 1.0) > WEIGHT_TOLERANCE
    check(not bool(np.any(bad)), f"{path.name}: skin weights of {int(bad.sum())} vertices do not sum to 1 "
                                 f"(worst sum {sums[bad][np.argmax(np.abs(sums[bad] - 1))]:.3g})"
          if np.any(bad) else "")
    wgt = wgt / sums[:, None]
    jnt = np.where(wgt > 0, old_to_new[jnt], 0)  # canonical index for zero weights (welding)
    pos = pos @ cg[:3, :3].T + cg[:3, 3]
    pos_w, faces_w, (jnt_w, wgt_w), index = weld(pos, faces, jnt, wgt)
    if have_normals:
        n = np.concatenate(nrm_l) @ np.linalg.inv(cg[:3, :3])  # inverse-transpose for normals
        acc = np.zeros((pos_w.shape[0], 3))
        np.add.at(acc, index, n)
        length = np.linalg.norm(acc, axis=1, keepdims=True)
        nrm_w = np.where(length > 1e-12, acc / np.maximum(length, 1e-30), vertex_normals(pos_w, faces_w))
    else:
        nrm_w = vertex_normals(pos_w, faces_w)

    # -- animations -------------------------------------------------------------------------------
    rest_trs = [_node_trs(nodes[n]) for n in jnodes]
    clips: dict[str, Clip] = {}
    animations = [(ai, anim) for ai, anim in enumerate(gltf.animations or [])
                  if any(c.target.node in node_to_joint and c.target.path in ("translation", "rotation", "scale")
                         for c in anim.channels)]
    names = clip_names([(ai, anim.name) for ai, anim in animations])
    for (ai, anim), cname in zip(animations, names, strict=True):
        chans = [c for c in anim.channels if c.target.node in node_to_joint and c.target.path in
                 ("translation", "rotation", "scale")]
        data = []
        for c in chans:
            smp = anim.samplers[c.sampler]
            times = reader.read(smp.input)[:, 0].astype(np.float64)
            check(times.size > 0 and bool(np.all(np.diff(times) >= 0)),
                  f"{path.name}: animation {ai} has an empty or decreasing time input")
            data.append((c, times, reader.read(smp.output).astype(np.float64), smp.interpolation or "LINEAR"))
        t0 = min(d[1][0] for d in data)
        t1 = max(d[1][-1] for d in data)
        nf = int(np.floor((t1 - t0) * fps + 1e-9)) + 1
        t = t0 + np.arange(nf) / fps
        tr = np.stack([np.tile(r[0], (nf, 1)) for r in rest_trs], axis=1)
        ro = np.stack([np.tile(r[1], (nf, 1)) for r in rest_trs], axis=1)
        sc = np.stack([np.tile(r[2], (nf, 1)) for r in rest_trs], axis=1)
        for c, times, out, interp in data:
            j = node_to_joint[c.target.node]
            if c.target.path == "rotation":
                ro[:, j] = _sample(times, out, interp, t, True)
            elif c.target.path == "translation":
                tr[:, j] = _sample(times, out, interp, t, False)
            else:
                sc[:, j] = _sample(times, out, interp, t, False)
        local = prefix[None] @ trs_matrix(tr, quat_to_matrix(ro), sc)
        clips[cname] = Clip(cname, fps, local)

    character = Character(name or path.stem, [nodes[n].name or f"joint_{n}" for n in jnodes], parents, bind_local,
                          inverse_bind, pos_w.astype(np.float32), nrm_w.astype(np.float32), faces_w, jnt_w,
                          wgt_w.astype(np.float32), clips)
    if height is not None:
        check(bool(np.isfinite(height)) and height > 0, f"height must be > 0, got {height}")
        extent = float(np.ptp(character.rest_vertices[:, 2]))
        check(extent > 0, f"{path.name}: the rest mesh has no vertical extent to scale")
        character = character.scaled(height / extent)
    return character
