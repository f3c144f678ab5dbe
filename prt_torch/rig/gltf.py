"""glTF 2.0 skinned characters -> :class:`~prt_torch.rig.character.Character` (pygltflib + numpy).

What is read:

* the default scene's node hierarchy; the skin of the first skinned mesh node (the primary skin) and every mesh
  node that belongs to its skeleton, merged into one character (all their triangle primitives): nodes using
  that skin, nodes with another skin over joints of the same skeleton (joint indices mapped, vertices moved into
  the primary mesh space), and rigid parts - mesh nodes without a skin below a joint (a sword, a helmet),
  skinned fully to their nearest joint ancestor (:func:`_mesh_parts`); other mesh nodes are left out with one
  warning line;
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
are averaged over welded duplicates. Weights are normalised to sum to one; where some vertex's sum is off
by more than ``WEIGHT_TOLERANCE`` (exporters that do not normalise) that is one warning line; a vertex whose
weights are all zero raises :class:`~prt_torch.errors.PrtError`.

Malformed files: :func:`read_document` checks the GLB container (magic, version, header and chunk
lengths against the file) and decodes every buffer (strict base64; truncated buffers rejected), then
:func:`validate_document` checks, in one pass before the loader touches anything, the node graph
(acyclic, at most one parent per node), every index, every accessor's byte span against its
bufferView and buffer (``count >= 1``, ``stride >= element size``), accessor types per use, node
transforms (16 / 3 / 4 / 3 finite numbers) and animation channel shapes. Data read later (positions,
times, matrices) is checked for NaN/inf, rest vertices for absurd coordinates and stray vertices
(:func:`check_extent`), and a clip is refused beyond ``MAX_CLIP_BYTES``. Every problem is one
:class:`~prt_torch.errors.PrtError` line.
"""

from __future__ import annotations

import base64
import binascii
import os
import struct
import urllib.parse
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch import limits as L
from prt_torch.errors import PrtError, check, warn
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.material import Material
from prt_torch.rig.mesh import vertex_normals, weld
from prt_torch.rig.rotations import Y_UP_TO_Z_UP, matrix_to_quat, quat_to_matrix, slerp, trs_matrix

WEIGHT_TOLERANCE = 0.02

#: the most bytes one decoded accessor (float64/int64) may take: a bound against absurd ``count`` values.
MAX_ACCESSOR_BYTES = 1 << 30
#: the most bytes of sampled joint transforms (``frames x joints x 4 x 4`` float64) one animation may take.
MAX_CLIP_BYTES = 1 << 30

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_C4 = np.eye(4)
_C4[:3, :3] = Y_UP_TO_Z_UP
_GLB_MAGIC, _GLB_JSON, _GLB_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")
_TRS_PATHS = {"translation": "VEC3", "rotation": "VEC4", "scale": "VEC3"}
_UNSIGNED = (5121, 5123, 5125)
#: attribute semantic -> (accessor types, component types, normalised allowed?) that the loader reads
_SEMANTICS: dict[str, tuple[tuple[str, ...], tuple[int, ...], bool | None]] = {
    "POSITION": (("VEC3",), (5126,), False),
    "NORMAL": (("VEC3",), (5126,), False),
    "JOINTS_0": (("VEC4",), (5121, 5123), False),
    "JOINTS_1": (("VEC4",), (5121, 5123), False),
    "WEIGHTS_0": (("VEC4",), (5126, 5121, 5123), None),
    "WEIGHTS_1": (("VEC4",), (5126, 5121, 5123), None),
    "TEXCOORD_0": (("VEC2",), (5126, 5121, 5123), None),
}


class _Checker:
    """Type and range checks of one document's JSON values; every failure is a one-line :class:`PrtError`."""

    def __init__(self, name: str) -> None:
        self.name = name

    def fail(self, message: str) -> None:
        raise PrtError(f"{self.name}: {message}")

    def that(self, condition: bool, message: str) -> None:
        if not condition:
            self.fail(message)

    def list(self, value: Any, what: str) -> list[Any]:
        if value is None:
            return []
        self.that(isinstance(value, list), f"{what} must be a JSON array, got {type(value).__name__}")
        return value

    def instance(self, value: Any, cls: type, what: str) -> None:
        self.that(isinstance(value, cls), f"{what} must be a JSON object, got {type(value).__name__}")

    def int(self, value: Any, what: str, minimum: int = 0, maximum: int | None = None,
            default: int | None = None) -> int:
        if value is None and default is not None:
            return default
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        self.that(ok, f"{what} must be an integer, got {value!r:.40}")
        self.that(value >= minimum and (maximum is None or value <= maximum),
                  f"{what} = {value} is out of range [{minimum}, {'inf' if maximum is None else maximum}]")
        return int(value)

    def index(self, value: Any, size: int, what: str) -> int:
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        self.that(ok, f"{what} must be an integer index, got {value!r:.40}")
        self.that(0 <= value < size, f"{what} = {value} is out of range (the file has {size})")
        return int(value)

    def numbers(self, value: Any, n: int, what: str) -> np.ndarray:
        ok = isinstance(value, (list, tuple)) and all(
            isinstance(x, (int, float, np.number)) and not isinstance(x, (bool, np.bool_)) for x in value)
        self.that(ok, f"{what} must be an array of {n} numbers")
        self.that(len(value) == n, f"{what} has {len(value)} numbers, expected {n}")
        arr = np.asarray(value, dtype=np.float64)
        self.that(bool(np.all(np.isfinite(arr))), f"{what} contains NaN or inf")
        return arr


@dataclass(frozen=True)
class DocumentGraph:
    """The node hierarchy of a validated document: ``parent (N,)`` int64 (-1 for a root), ``depth (N,)`` int64."""

    parent: np.ndarray
    depth: np.ndarray


def _parse_glb(raw: bytes, name: str) -> tuple[bytes, bytes | None]:
    """GLB container -> ``(JSON chunk, BIN chunk or None)``; header and chunk lengths are checked against the file."""
    check(len(raw) >= 12, f"{name}: truncated GLB header ({len(raw)} bytes)")
    magic, version, length = struct.unpack_from("<III", raw, 0)
    check(magic == _GLB_MAGIC, f"{name}: not a binary glTF file (bad GLB magic)")
    check(version == 2, f"{name}: unsupported GLB container version {version} (expected 2)")
    check(length == len(raw), f"{name}: the GLB header says {length} bytes but the file has {len(raw)}"
                              f"{' (truncated)' if length > len(raw) else ''}")
    pos, k = 12, 0
    json_chunk: bytes | None = None
    bin_chunk: bytes | None = None
    while pos < length:
        check(pos + 8 <= length, f"{name}: truncated GLB chunk header at byte {pos}")
        clen, ctype = struct.unpack_from("<II", raw, pos)
        check(pos + 8 + clen <= length, f"{name}: GLB chunk {k} length {clen} runs past the end of the file "
                                        f"({length - pos - 8} bytes left)")
        body = raw[pos + 8:pos + 8 + clen]
        if k == 0:
            check(ctype == _GLB_JSON, f"{name}: the first GLB chunk is not JSON (type 0x{ctype:08x})")
            json_chunk = body
        elif ctype == _GLB_BIN:
            check(k == 1, f"{name}: the GLB BIN chunk must be the second chunk, found it as chunk {k}")
            bin_chunk = body
        pos, k = pos + 8 + clen, k + 1
    check(json_chunk is not None, f"{name}: GLB file has no JSON chunk")
    assert json_chunk is not None
    return json_chunk, bin_chunk


def _load_buffers(gltf: Any, path: Path, bin_chunk: bytes | None) -> list[bytes]:
    """The bytes of every buffer (GLB BIN chunk, base64 data URI or external file), each cut to its byteLength."""
    import pygltflib

    v = _Checker(path.name)
    out: list[bytes] = []
    for i, buf in enumerate(v.list(gltf.buffers, "buffers")):
        v.instance(buf, pygltflib.Buffer, f"buffer {i}")
        n = v.int(buf.byteLength, f"buffer {i} byteLength", minimum=1)
        uri = buf.uri
        if uri is None:
            v.that(bin_chunk is not None, f"buffer {i} has no data (no uri and no GLB binary chunk)")
            assert bin_chunk is not None
            data = bin_chunk
        elif not isinstance(uri, str):
            v.fail(f"buffer {i} uri must be a string")
        elif uri.startswith("data:"):
            header, sep, payload = uri.partition(",")
            v.that(bool(sep) and header.endswith(";base64"), f"buffer {i}: unsupported data URI (expected ';base64,')")
            try:
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError):
                v.fail(f"buffer {i}: bad base64 data URI")
        else:
            v.that("://" not in uri, f"buffer {i}: unsupported external URI {uri[:60]!r} (only relative file paths)")
            f = path.parent / urllib.parse.unquote(uri)
            v.that(f.is_file(), f"external buffer not found: {f}")
            with open(f, "rb") as fh:
                data = fh.read(n)
        v.that(len(data) >= n, f"buffer {i} is shorter than its byteLength ({len(data)} < {n} bytes: truncated)")
        out.append(bytes(data[:n]))
    return out


def read_document(path: str | os.PathLike[str]) -> tuple[Any, list[bytes]]:
    """Parse a ``.glb``/``.gltf`` file -> ``(pygltflib.GLTF2, buffers)`` (the GLB container checked, buffers
    decoded and cut to their byteLength), without :func:`validate_document`. Raises :class:`PrtError`."""
    import pygltflib

    path = Path(path)
    raw = path.read_bytes()
    bin_chunk = None
    if raw[:4] == b"glTF":
        text_bytes, bin_chunk = _parse_glb(raw, path.name)
    else:
        check(path.suffix.lower() != ".glb", f"{path.name}: not a binary glTF file (bad GLB magic)")
        text_bytes = raw
    try:
        text = text_bytes.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise PrtError(f"{path.name}: the glTF JSON is not valid UTF-8") from None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            gltf = pygltflib.GLTF2.gltf_from_json(text)
        except Exception as e:  # json / dataclasses_json raise assorted errors on malformed documents
            raise PrtError(f"cannot parse glTF file {path.name}: {type(e).__name__}") from None
    check(isinstance(gltf, pygltflib.GLTF2), f"cannot parse glTF file {path.name}: not a glTF document")
    return gltf, _load_buffers(gltf, path, bin_chunk)


def _depths(parent: np.ndarray, v: _Checker) -> np.ndarray:
    """Depth of every node below its root; a cycle is a :class:`PrtError` (each node has at most one parent)."""
    n = parent.size
    depth = np.full(n, -1, dtype=np.int64)  # -1 unknown, -2 on the path being walked
    for start in range(n):
        path: list[int] = []
        i = start
        while i >= 0 and depth[i] == -1:
            depth[i] = -2
            path.append(i)
            i = int(parent[i])
        if i >= 0 and depth[i] == -2:
            v.fail(f"the node hierarchy has a cycle through node {i}")
        d = -1 if i < 0 else int(depth[i])
        for k in reversed(path):
            d += 1
            depth[k] = d
    return depth


def validate_document(gltf: Any, buffers: list[bytes], name: str = "glTF") -> DocumentGraph:
    """Check everything the loader uses before it is used; returns the node hierarchy.

    The node graph (every node at most one parent, no cycles, no node its own child), every index
    (scene, node, child, mesh, skin, accessor, bufferView, buffer, animation sampler), the types of
    the accessors the loader reads, and every accessor's byte span
    (``offset + stride * (count - 1) + element size <= bufferView length``, bufferView spans within
    their buffers, ``stride >= element size``, ``count >= 1``), node transforms (16 / 3 / 4 / 3 finite
    numbers) and animation channel shapes. Raises :class:`PrtError` with one line naming the problem.
    """
    import pygltflib

    v = _Checker(name)
    nodes = v.list(gltf.nodes, "nodes")
    meshes = v.list(gltf.meshes, "meshes")
    skins = v.list(gltf.skins, "skins")
    accessors = v.list(gltf.accessors, "accessors")
    views = v.list(gltf.bufferViews, "bufferViews")
    v.that(len(v.list(gltf.buffers, "buffers")) == len(buffers), "buffers do not match the document")

    for i, bv in enumerate(views):
        v.instance(bv, pygltflib.BufferView, f"bufferView {i}")
        b = v.index(bv.buffer, len(buffers), f"bufferView {i} buffer")
        off = v.int(bv.byteOffset, f"bufferView {i} byteOffset", default=0)
        length = v.int(bv.byteLength, f"bufferView {i} byteLength", minimum=1)
        v.that(off + length <= len(buffers[b]), f"bufferView {i} (bytes {off}..{off + length}) runs past the end "
                                               f"of buffer {b} ({len(buffers[b])} bytes)")
        if bv.byteStride is not None:
            v.int(bv.byteStride, f"bufferView {i} byteStride", minimum=4, maximum=252)

    def span(view: Any, offset: Any, elem: int, count: int, what: str) -> None:
        vi = v.index(view, len(views), f"{what} bufferView")
        off = v.int(offset, f"{what} byteOffset", default=0)
        stride = views[vi].byteStride or elem
        v.that(stride >= elem, f"{what}: byteStride {stride} of bufferView {vi} is smaller than the element size "
                               f"{elem} bytes")
        end = off + stride * (count - 1) + elem
        v.that(end <= views[vi].byteLength, f"{what}: {count} elements of {elem} bytes (stride {stride}, offset {off}) "
                                            f"need {end} bytes but bufferView {vi} has {views[vi].byteLength}")

    for i, acc in enumerate(accessors):
        what = f"accessor {i}"
        v.instance(acc, pygltflib.Accessor, what)
        v.that(acc.componentType in _COMPONENT and not isinstance(acc.componentType, bool),
               f"{what}: unsupported componentType {acc.componentType!r:.20}")
        v.that(acc.type in _NCOMP, f"{what}: unsupported accessor type {acc.type!r:.20}")
        v.that(acc.normalized is None or isinstance(acc.normalized, bool), f"{what}: normalized must be a boolean")
        count = v.int(acc.count, f"{what} count", minimum=1)
        size, ncomp = np.dtype(_COMPONENT[acc.componentType]).itemsize, _NCOMP[acc.type]
        v.that(count * ncomp * 8 <= MAX_ACCESSOR_BYTES, f"{what}: count {count} would decode to "
               f"{count * ncomp * 8 / 2**30:.1f} GiB (limit {MAX_ACCESSOR_BYTES / 2**30:.0f} GiB)")
        if acc.bufferView is not None:
            span(acc.bufferView, acc.byteOffset, size * ncomp, count, what)
        if acc.sparse is not None:
            sp = acc.sparse
            v.instance(sp, pygltflib.Sparse, f"{what} sparse")
            sc = v.int(sp.count, f"{what} sparse count", minimum=1, maximum=count)
            v.instance(sp.indices, pygltflib.AccessorSparseIndices, f"{what} sparse indices")
            v.instance(sp.values, pygltflib.AccessorSparseValues, f"{what} sparse values")
            v.that(sp.indices.componentType in _UNSIGNED, f"{what}: unsupported sparse index componentType "
                                                          f"{sp.indices.componentType!r:.20}")
            span(sp.indices.bufferView, sp.indices.byteOffset,
                 np.dtype(_COMPONENT[sp.indices.componentType]).itemsize, sc, f"{what} sparse indices")
            span(sp.values.bufferView, sp.values.byteOffset, size * ncomp, sc, f"{what} sparse values")

    def accessor(index: Any, what: str, types: tuple[str, ...], ctypes: tuple[int, ...],
                 normalized: bool | None = None) -> int:
        a = v.index(index, len(accessors), what)
        acc = accessors[a]
        v.that(acc.type in types and acc.componentType in ctypes,
               f"{what}: accessor {a} is {acc.type} of componentType {acc.componentType}, expected "
               f"{'/'.join(types)} of {'/'.join(map(str, ctypes))}")
        if normalized is not None:
            v.that(bool(acc.normalized) == normalized or acc.componentType == 5126,
                   f"{what}: accessor {a} must {'' if normalized else 'not '}be normalized")
        return a

    for mi, mesh in enumerate(meshes):
        v.instance(mesh, pygltflib.Mesh, f"mesh {mi}")
        prims = v.list(mesh.primitives, f"mesh {mi} primitives")
        v.that(len(prims) > 0, f"mesh {mi} has no primitives")
        for pi, prim in enumerate(prims):
            what = f"mesh {mi} primitive {pi}"
            v.instance(prim, pygltflib.Primitive, what)
            if prim.mode is not None:
                v.int(prim.mode, f"{what} mode", maximum=6)
            v.instance(prim.attributes, pygltflib.Attributes, f"{what} attributes")
            counts: dict[str, int] = {}
            for sem, idx in vars(prim.attributes).items():
                if idx is None:
                    continue
                if sem in _SEMANTICS:
                    types, ctypes, norm = _SEMANTICS[sem]
                    a = accessor(idx, f"{what} {sem}", types, ctypes,
                                 True if norm is None else norm)  # integer weights must be normalized
                else:
                    a = v.index(idx, len(accessors), f"{what} attribute {sem}")
                counts[sem] = accessors[a].count
            v.that(len(set(counts.values())) <= 1, f"{what}: attributes have different counts {counts}")
            if prim.indices is not None:
                a = accessor(prim.indices, f"{what} indices", ("SCALAR",), _UNSIGNED, False)
                if prim.mode in (None, 4):
                    v.that(accessors[a].count % 3 == 0, f"{what}: triangle index count {accessors[a].count} is "
                                                        f"not a multiple of 3")

    parent = np.full(len(nodes), -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        what = f"node {i}"
        v.instance(node, pygltflib.Node, what)
        if node.mesh is not None:
            v.index(node.mesh, len(meshes), f"{what} mesh")
        if node.skin is not None:
            v.index(node.skin, len(skins), f"{what} skin")
        for c in v.list(node.children, f"{what} children"):
            c = v.index(c, len(nodes), f"{what} child")
            v.that(c != i, f"{what} lists itself as a child")
            v.that(parent[c] < 0, f"node {c} has two parents (nodes {parent[c]} and {i})")
            parent[c] = i
        if node.matrix is not None:
            v.numbers(node.matrix, 16, f"{what} matrix")
        if node.translation is not None:
            v.numbers(node.translation, 3, f"{what} translation")
        if node.rotation is not None:
            v.that(bool(np.linalg.norm(v.numbers(node.rotation, 4, f"{what} rotation")) > 1e-12),
                   f"{what} rotation is a zero quaternion")
        if node.scale is not None:
            v.numbers(node.scale, 3, f"{what} scale")
    depth = _depths(parent, v)

    scenes = v.list(gltf.scenes, "scenes")
    for si, scene in enumerate(scenes):
        v.instance(scene, pygltflib.Scene, f"scene {si}")
        for n in v.list(scene.nodes, f"scene {si} nodes"):
            v.index(n, len(nodes), f"scene {si} node")
    if gltf.scene is not None:
        v.index(gltf.scene, len(scenes), "scene")

    for si, skin in enumerate(skins):
        v.instance(skin, pygltflib.Skin, f"skin {si}")
        joints = [v.index(j, len(nodes), f"skin {si} joint") for j in v.list(skin.joints, f"skin {si} joints")]
        v.that(len(joints) > 0, f"skin {si} has no joints")
        v.that(len(set(joints)) == len(joints), f"skin {si} lists a joint node twice")
        if skin.inverseBindMatrices is not None:
            a = accessor(skin.inverseBindMatrices, f"skin {si} inverseBindMatrices", ("MAT4",), (5126,))
            v.that(accessors[a].count == len(joints), f"skin {si}: {accessors[a].count} inverse bind matrices for "
                                                      f"{len(joints)} joints")
        if skin.skeleton is not None:
            v.index(skin.skeleton, len(nodes), f"skin {si} skeleton")

    for ai, anim in enumerate(v.list(gltf.animations, "animations")):
        what = f"animation {ai}"
        v.instance(anim, pygltflib.Animation, what)
        samplers = v.list(anim.samplers, f"{what} samplers")
        keys = []
        for si, smp in enumerate(samplers):
            v.instance(smp, pygltflib.AnimationSampler, f"{what} sampler {si}")
            a_in = accessor(smp.input, f"{what} sampler {si} input", ("SCALAR",), (5126,))
            a_out = accessor(smp.output, f"{what} sampler {si} output", tuple(_NCOMP), tuple(_COMPONENT), True)
            interp = smp.interpolation or "LINEAR"
            v.that(interp in _INTERPOLATIONS, f"{what} sampler {si}: unknown interpolation {interp!r:.30}")
            keys.append((accessors[a_in].count, accessors[a_out], interp))
        for ci, ch in enumerate(v.list(anim.channels, f"{what} channels")):
            v.instance(ch, pygltflib.AnimationChannel, f"{what} channel {ci}")
            s = v.index(ch.sampler, len(samplers), f"{what} channel {ci} sampler")
            v.instance(ch.target, pygltflib.AnimationChannelTarget, f"{what} channel {ci} target")
            v.that(isinstance(ch.target.path, str), f"{what} channel {ci}: target path must be a string")
            if ch.target.node is None:
                continue
            v.index(ch.target.node, len(nodes), f"{what} channel {ci} target node")
            if ch.target.path in _TRS_PATHS:
                nkeys, out, interp = keys[s]
                want = 3 * nkeys if interp == "CUBICSPLINE" else nkeys
                v.that(out.type == _TRS_PATHS[ch.target.path] and out.count == want,
                       f"{what} channel {ci} ({ch.target.path}, {interp}): sampler output is {out.count} x {out.type}, "
                       f"expected {want} x {_TRS_PATHS[ch.target.path]}")
    return DocumentGraph(parent, depth)


class _Reader:
    """Accessor data of one validated glTF document as numpy arrays."""

    def __init__(self, gltf: Any, buffers: list[bytes], name: str) -> None:  # gltf: pygltflib.GLTF2
        self.gltf = gltf
        self.buffers = buffers
        self.name = name

    def _view(self, view_index: int, offset: int, dtype: np.dtype, count: int, ncomp: int) -> np.ndarray:
        view = self.gltf.bufferViews[view_index]
        data = self.buffers[view.buffer]
        start = (view.byteOffset or 0) + offset
        item = np.dtype(dtype).itemsize * ncomp
        stride = view.byteStride or item
        end = start + stride * (count - 1) + item if count else start
        check(stride >= item and end <= len(data), f"{self.name}: accessor reads past the end of its buffer")
        raw = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
        if stride == item:
            return np.frombuffer(raw.tobytes(), dtype=dtype).reshape(count, ncomp)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1))
        return np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype).reshape(count, ncomp)

    def read(self, accessor_index: int) -> np.ndarray:
        """Accessor -> ``(count, ncomp)`` array (float64 for normalised/float data, int64 otherwise)."""
        check(0 <= accessor_index < len(self.gltf.accessors), f"{self.name}: bad accessor {accessor_index}")
        acc = self.gltf.accessors[accessor_index]
        dtype, ncomp = np.dtype(_COMPONENT[acc.componentType]), _NCOMP[acc.type]
        if acc.bufferView is None:
            out = np.zeros((acc.count, ncomp), dtype=dtype)
        else:
            out = self._view(acc.bufferView, acc.byteOffset or 0, dtype, acc.count, ncomp).copy()
        if acc.sparse is not None:
            sp = acc.sparse
            idx = self._view(sp.indices.bufferView, sp.indices.byteOffset or 0,
                             np.dtype(_COMPONENT[sp.indices.componentType]), sp.count, 1)[:, 0].astype(np.int64)
            check(bool(np.all(idx < acc.count)), f"{self.name}: accessor {accessor_index} has sparse indices out of "
                                                 f"range [0, {acc.count})")
            out[idx] = self._view(sp.values.bufferView, sp.values.byteOffset or 0, dtype, sp.count, ncomp)
        if np.issubdtype(dtype, np.floating):
            out64 = out.astype(np.float64)
            check(bool(np.all(np.isfinite(out64))), f"{self.name}: accessor {accessor_index} contains NaN or inf")
            return out64
        if acc.normalized:
            info = np.iinfo(dtype)
            return np.maximum(out.astype(np.float64) / info.max, -1.0)
        return out.astype(np.int64)


def _node_matrix(node: Any) -> np.ndarray:
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
    return trs_matrix(node.translation, node.rotation, node.scale)


def _node_trs(node: Any, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if node.matrix is not None:
        m = _node_matrix(node)
        s = np.linalg.norm(m[:3, :3], axis=0)
        check(bool(np.all(s > 1e-12)), f"{name}: the matrix of joint node {node.name or ''!r} is singular")
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


def check_extent(positions: np.ndarray, name: str) -> None:
    """Refuse rest vertex ``positions (N, 3)`` (z-up world, file units) with a coordinate beyond
    :data:`~prt_torch.limits.MAX_COORDINATE`, or a vertex farther from the per-axis median than
    :data:`~prt_torch.limits.MAX_VERTEX_SPREAD` times the median vertex distance from it (a stray vertex: it
    would set the character's size and bounds); one :class:`PrtError` line naming the vertex."""
    big = np.abs(positions).max(axis=1)
    i = int(np.argmax(big))
    check(big[i] <= L.MAX_COORDINATE, f"{name}: vertex {i} at {_point(positions[i])} has a coordinate beyond "
                                      f"{L.MAX_COORDINATE:g} (limits.MAX_COORDINATE)")
    dist = np.linalg.norm(positions - np.median(positions, axis=0), axis=1)
    typical = float(np.median(dist))
    if typical > 0:  # else most vertices coincide: nothing to measure a stray one against
        i = int(np.argmax(dist))
        ratio = float(dist[i]) / typical
        check(ratio <= L.MAX_VERTEX_SPREAD, f"{name}: vertex {i} at {_point(positions[i])} lies {ratio:.0f} times "
                                            f"the median vertex distance ({typical:.3g}) from the mesh's median, over "
                                            f"{L.MAX_VERTEX_SPREAD:g} (limits.MAX_VERTEX_SPREAD): a stray vertex")


def _point(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(x):.4g}" for x in p) + ")"


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
    The document is checked by :func:`validate_document` before anything is read from it; every bad
    input raises :class:`PrtError` with a one-line message.
    """
    path = Path(path)
    check(path.is_file(), f"glTF file not found: {path}")
    check(path.suffix.lower() in (".glb", ".gltf"), f"unknown character file format {path.suffix!r}: {path.name}")
    check(bool(np.isfinite(fps)) and fps > 0, f"fps must be > 0, got {fps}")
    if height is not None:
        check(bool(np.isfinite(height)) and height > 0, f"height must be > 0, got {height}")
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numeric chatter: every result is checked for NaN/inf instead
        gltf, buffers = read_document(path)
        graph = validate_document(gltf, buffers, path.name)
        notes: list[str] = []
        try:
            character = _build(gltf, buffers, graph, path, fps, name, notes)
        except np.linalg.LinAlgError:
            raise PrtError(f"{path.name}: singular joint or bind transform") from None
        if height is not None:
            extent = float(np.ptp(character.rest_vertices[:, 2]))
            check(extent > 0, f"{path.name}: the rest mesh has no vertical extent to scale")
            character = character.scaled(height / extent)
    for message in notes:  # outside the numeric-chatter filter above
        warn(message)
    return character


def _build(gltf: Any, buffers: list[bytes], graph: DocumentGraph, path: Path, fps: float,
           name: str | None, notes: list[str]) -> Character:
    """The loader proper, on a document :func:`validate_document` accepted; one-line warnings go to ``notes``."""
    check(len(gltf.nodes) > 0, f"glTF file {path.name} has no nodes")
    reader = _Reader(gltf, buffers, path.name)
    nodes = gltf.nodes
    parent, depth = graph.parent, graph.depth
    skinned = [i for i, n in enumerate(nodes) if n.mesh is not None and n.skin is not None]
    check(len(skinned) > 0, f"glTF file {path.name} has no skinned mesh (no node with both a mesh and a skin)")
    skin_index = nodes[skinned[0]].skin
    skin = gltf.skins[skin_index]
    joint_nodes = list(skin.joints)
    check(len(joint_nodes) > 0, f"glTF skin {skin_index} of {path.name} has no joints")
    joint_set = set(joint_nodes)

    order = sorted(range(len(joint_nodes)), key=lambda k: (depth[joint_nodes[k]], k))  # parents first
    old_to_new = np.empty(len(joint_nodes), dtype=np.int64)
    old_to_new[order] = np.arange(len(order))
    jnodes = [joint_nodes[k] for k in order]
    node_to_joint = {n: j for j, n in enumerate(jnodes)}
    parents = np.empty(len(jnodes), dtype=np.int64)
    prefix = np.empty((len(jnodes), 4, 4))
    for j, n in enumerate(jnodes):
        m = np.eye(4)
        a = int(parent[n])
        while a >= 0 and a not in joint_set:  # terminates: validate_document rejects cycles
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
    check(bool(np.all(np.abs(np.linalg.det(ibm[:, :3, :3])) > 1e-30)), f"{path.name}: singular inverse bind matrix")
    # mesh space -> glTF world at the node rest pose; exact posing holds for any invertible G, and
    # for a rig bound at its rest pose G is the same for every joint (the bind pose is the rest pose)
    node_world = np.empty((len(nodes), 4, 4))
    for i in np.argsort(depth, kind="stable"):
        node_world[i] = _node_matrix(nodes[i]) if parent[i] < 0 else node_world[parent[i]] @ _node_matrix(nodes[i])
    g = node_world[jnodes[0]] @ ibm[0]
    check(bool(np.all(np.isfinite(g))) and abs(np.linalg.det(g[:3, :3])) > 1e-12,
          f"{path.name}: singular bind transform")
    cg = _C4 @ g
    parts = _mesh_parts(gltf, reader, graph, path, skin_index, node_world, g, notes)
    bind_world = cg[None] @ np.linalg.inv(ibm)
    inverse_bind = ibm @ np.linalg.inv(cg)[None]
    check(bool(np.all(np.isfinite(bind_world))) and bool(np.all(np.isfinite(inverse_bind))),
          f"{path.name}: bind transforms overflow (NaN or inf)")
    bind_local = bind_world.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            bind_local[j] = np.linalg.solve(bind_world[p], bind_world[j])

    # -- geometry ---------------------------------------------------------------------------------
    pos_l, jnt_l, wgt_l, face_l, uv_l, mat_l = [], [], [], [], [], []
    nrm_l: list[np.ndarray | None] = []
    offset = 0
    for part in parts:
        for prim in gltf.meshes[nodes[part.node].mesh].primitives:
            if prim.mode not in (None, 4):
                continue  # points/lines/strips are not surfaces we can shade
            at = prim.attributes
            check(at.POSITION is not None, f"{path.name}: a primitive has no POSITION")
            p = reader.read(at.POSITION)
            if part.rigid_joint is not None:  # a rigid part: skinned fully to the joint it hangs from
                jt = np.full((p.shape[0], 1), part.rigid_joint, dtype=np.int64)
                wt = np.ones((p.shape[0], 1))
            else:
                check(at.JOINTS_0 is not None and at.WEIGHTS_0 is not None,
                      f"{path.name}: a skinned primitive has no JOINTS_0/WEIGHTS_0")
                jt = reader.read(at.JOINTS_0)
                wt = reader.read(at.WEIGHTS_0).astype(np.float64)
                if getattr(at, "JOINTS_1", None) is not None and getattr(at, "WEIGHTS_1", None) is not None:
                    jt = np.concatenate([jt, reader.read(at.JOINTS_1)], axis=1)
                    wt = np.concatenate([wt, reader.read(at.WEIGHTS_1).astype(np.float64)], axis=1)
                check(bool(np.all((jt >= 0) & (jt < part.joint_map.size))),
                      f"{path.name}: JOINTS_0 index out of range in mesh node {part.label}")
                jt = part.joint_map[jt]
            if part.to_mesh is not None:  # into the primary skin's mesh space
                check(bool(np.all(np.isfinite(p))), f"{path.name}: vertex positions contain NaN or inf")
                p = p @ part.to_mesh[:3, :3].T + part.to_mesh[:3, 3]
            idx = (np.arange(p.shape[0]) if prim.indices is None else reader.read(prim.indices)[:, 0])
            check(idx.size % 3 == 0, f"{path.name}: triangle primitive index count is not a multiple of 3")
            check(bool(np.all(idx < p.shape[0])), f"{path.name}: triangle indices out of range")
            if at.NORMAL is not None:
                n_part = reader.read(at.NORMAL)
                nrm_l.append(n_part if part.to_mesh is None else n_part @ np.linalg.inv(part.to_mesh[:3, :3]))
            else:
                nrm_l.append(None)
            pos_l.append(p)
            uv_l.append(reader.read(at.TEXCOORD_0) if getattr(at, "TEXCOORD_0", None) is not None else None)
            mat_l.append(prim.material)
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
    check(faces.shape[0] > 0, f"{path.name}: the skinned mesh has no triangles")
    check(bool(np.all(np.isfinite(pos))), f"{path.name}: vertex positions contain NaN or inf")
    check(bool(np.all(np.isfinite(wgt))), f"{path.name}: skin weights contain NaN or inf")
    check(bool(np.all((faces >= 0) & (faces < pos.shape[0]))), f"{path.name}: triangle indices out of range")
    check(bool(np.all((jnt >= 0) & (jnt < len(joint_nodes)))), f"{path.name}: JOINTS_0 index out of range")
    sums = wgt.sum(axis=1)
    check(bool(np.all(sums > 0)), f"{path.name}: {int((sums <= 0).sum())} vertices have skin weights that are all "
                                  f"zero (no joint moves them)")
    bad = np.abs(sums - 1.0) > WEIGHT_TOLERANCE
    if np.any(bad):
        notes.append(f"{path.name}: skin weights of {int(bad.sum())} vertices do not sum to 1 (sums "
                     f"{sums[bad].min():.3g}..{sums[bad].max():.3g}); normalised")
    wgt = wgt / sums[:, None]
    jnt = np.where(wgt > 0, old_to_new[jnt], 0)  # canonical index for zero weights (welding)
    pos = pos @ cg[:3, :3].T + cg[:3, 3]
    check(bool(np.all(np.isfinite(pos.astype(np.float32)))), f"{path.name}: rest vertex positions overflow")
    check_extent(pos, path.name)
    pos_w, faces_w, (jnt_w, wgt_w), index = weld(pos, faces, jnt, wgt)
    check(faces_w.shape[0] > 0, f"{path.name}: every triangle of the skinned mesh is degenerate")
    if any(n is not None for n in nrm_l):  # file normals; a part without them (a rigid prop) gets its own, area
        # weighted over its own triangles in mesh space (a file without any normals is smoothed after welding)
        starts = np.cumsum([0] + [q.shape[0] for q in pos_l[:-1]])
        nrm_l = [m if m is not None else vertex_normals(q, f - s0).astype(np.float64)
                 for m, q, f, s0 in zip(nrm_l, pos_l, face_l, starts, strict=True)]
        n = np.concatenate(nrm_l) @ np.linalg.inv(cg[:3, :3])  # inverse-transpose for normals
        acc = np.zeros((pos_w.shape[0], 3))
        np.add.at(acc, index, n)
        length = np.linalg.norm(acc, axis=1, keepdims=True)
        nrm_w = np.where(length > 1e-12, acc / np.maximum(length, 1e-30), vertex_normals(pos_w, faces_w))
    else:
        nrm_w = vertex_normals(pos_w, faces_w)

    # -- animations -------------------------------------------------------------------------------
    rest_trs = [_node_trs(nodes[n], path.name) for n in jnodes]
    clips: dict[str, Clip] = {}
    animations = [(ai, anim) for ai, anim in enumerate(gltf.animations or [])
                  if any(c.target.node in node_to_joint and c.target.path in _TRS_PATHS for c in anim.channels)]
    names = clip_names([(ai, anim.name if isinstance(anim.name, str) else None) for ai, anim in animations])
    for (ai, anim), cname in zip(animations, names, strict=True):
        chans = [c for c in anim.channels if c.target.node in node_to_joint and c.target.path in _TRS_PATHS]
        data = []
        for c in chans:
            smp = anim.samplers[c.sampler]
            times = reader.read(smp.input)[:, 0].astype(np.float64)
            check(times.size > 0 and bool(np.all(np.diff(times) >= 0)),
                  f"{path.name}: animation {ai} has an empty or decreasing time input")
            data.append((c, times, reader.read(smp.output).astype(np.float64), smp.interpolation or "LINEAR"))
        t0 = min(d[1][0] for d in data)
        t1 = max(d[1][-1] for d in data)
        frames = (t1 - t0) * fps
        need = (frames + 1) * len(jnodes) * 16 * 8
        check(need <= MAX_CLIP_BYTES, f"{path.name}: animation {ai} spans {t1 - t0:.6g} s = {frames + 1:.3g} frames at "
                                      f"{fps:g} fps: {need / 2**30:.3g} GiB of joint transforms exceeds the "
                                      f"{MAX_CLIP_BYTES / 2**30:.0f} GiB limit")
        nf = int(np.floor(frames + 1e-9)) + 1
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
        check(bool(np.all(np.isfinite(local))), f"{path.name}: animation {ai} gives NaN or inf joint transforms "
                                                f"(zero quaternion or overflow)")
        clips[cname] = Clip(cname, fps, local)

    jname = [nodes[n].name if isinstance(nodes[n].name, str) and nodes[n].name else f"joint_{n}" for n in jnodes]
    material, uv = _material_and_uv(gltf, reader, path, mat_l, uv_l, pos_l, faces, faces_w, index)
    return Character(name or path.stem, jname, parents, bind_local, inverse_bind, pos_w.astype(np.float32),
                     nrm_w.astype(np.float32), faces_w, jnt_w, wgt_w.astype(np.float32), clips, uv=uv,
                     material=material)


@dataclass(frozen=True)
class _MeshPart:
    """One mesh node of the character: ``node`` its index, ``label`` its name for messages; ``joint_map (K,)`` int64
    its skin's joint indices -> the primary skin's (``None`` for a rigid part), ``rigid_joint`` the primary skin's
    joint index a rigid part is skinned to fully (else ``None``), ``to_mesh (4, 4)`` its mesh space -> the primary
    skin's mesh space (``None``: the same space)."""

    node: int
    label: str
    joint_map: np.ndarray | None
    rigid_joint: int | None
    to_mesh: np.ndarray | None


def _mesh_parts(gltf: Any, reader: _Reader, graph: DocumentGraph, path: Path, skin_index: int,
                node_world: np.ndarray, g: np.ndarray, notes: list[str]) -> list[_MeshPart]:
    """The mesh nodes that make one character with skin ``skin_index`` (the primary skin), in node order.

    * every node skinned with the primary skin;
    * a node with another skin whose joints are all joints of the primary skin: its joint indices are mapped to
      the primary skin's, its vertices moved into the primary mesh space by ``inv(G) @ G2`` (``G2 =
      world_rest(joint_0) @ IBM_0`` of its own skin; ``g`` is the primary's ``G``, ``node_world (N, 4, 4)`` the
      nodes' rest world transforms);
    * a mesh node without a skin below a joint of the primary skin (itself or its nearest joint ancestor): a rigid
      part, skinned fully to that joint, its vertices moved by ``inv(G) @ world_rest(node)``.

    Any other mesh node (another skeleton, or not attached to one) is left out with one line in ``notes``.
    """
    nodes = gltf.nodes
    joints = list(gltf.skins[skin_index].joints)
    index_of = {n: k for k, n in enumerate(joints)}
    inv_g = np.linalg.inv(g)
    parts: list[_MeshPart] = []
    left_out: list[str] = []
    for i, node in enumerate(nodes):
        if node.mesh is None:
            continue
        label = node.name if isinstance(node.name, str) and node.name else f"node_{i}"
        if node.skin == skin_index:
            parts.append(_MeshPart(i, label, np.arange(len(joints), dtype=np.int64), None, None))
        elif node.skin is not None:
            other = gltf.skins[node.skin]
            if not all(j in index_of for j in other.joints):
                left_out.append(f"{label!r} (skin {node.skin} has joints outside skin {skin_index})")
                continue
            if other.inverseBindMatrices is not None:
                ibm0 = reader.read(other.inverseBindMatrices).reshape(-1, 4, 4)[0].T
            else:
                ibm0 = np.eye(4)
            to_mesh = inv_g @ node_world[other.joints[0]] @ ibm0
            check(bool(np.all(np.isfinite(to_mesh))), f"{path.name}: singular bind transform of mesh node {label!r}")
            parts.append(_MeshPart(i, label, np.array([index_of[j] for j in other.joints], dtype=np.int64), None,
                                   to_mesh))
        else:
            a = i
            while a >= 0 and a not in index_of:  # terminates: validate_document rejects cycles
                a = int(graph.parent[a])
            if a < 0:
                left_out.append(f"{label!r} (no skin and no joint above it)")
                continue
            to_mesh = inv_g @ node_world[i]
            check(bool(np.all(np.isfinite(to_mesh))), f"{path.name}: singular transform of mesh node {label!r}")
            parts.append(_MeshPart(i, label, None, index_of[a], to_mesh))
    if left_out:
        notes.append(f"{path.name}: {len(left_out)} mesh node(s) not part of the character, left out: "
                     f"{', '.join(left_out[:4])}{', ...' if len(left_out) > 4 else ''}")
    return parts


def _material_and_uv(gltf: Any, reader: _Reader, path: Path, mat_l: list[Any], uv_l: list[Any],
                     pos_l: list[np.ndarray], faces: np.ndarray, faces_w: np.ndarray, index: np.ndarray
                     ) -> tuple[Material | None, np.ndarray | None]:
    """The first primitive's ``pbrMetallicRoughness`` material (base colour factor + texture, metallic,
    roughness) and per-corner ``TEXCOORD_0`` of the welded faces ``(T', 3, 2)`` (``None`` without UVs)."""
    mi = next((m for m in mat_l if m is not None), None)
    if mi is None:
        return None, None
    mats = gltf.materials or []
    check(isinstance(mi, int) and 0 <= mi < len(mats), f"{path.name}: primitive material {mi} out of range")
    mat = mats[mi]
    pbr = mat.pbrMetallicRoughness
    factor = (1.0, 1.0, 1.0, 1.0) if pbr is None or pbr.baseColorFactor is None else pbr.baseColorFactor
    metallic = 1.0 if pbr is None or pbr.metallicFactor is None else pbr.metallicFactor
    roughness = 1.0 if pbr is None or pbr.roughnessFactor is None else pbr.roughnessFactor
    texture = None
    info = None if pbr is None else pbr.baseColorTexture
    if info is not None and all(u is not None for u in uv_l) and (info.texCoord or 0) == 0:
        texture = _read_image(gltf, reader, path, info.index)
    uv = None
    if texture is not None:
        uv_all = np.concatenate(uv_l)  # per original vertex; faces index it
        # welding keeps faces (dropping degenerate ones) in order: recover each kept face's original corners
        mapped = index[faces]
        ok = (mapped[:, 0] != mapped[:, 1]) & (mapped[:, 1] != mapped[:, 2]) & (mapped[:, 0] != mapped[:, 2])
        check(int(ok.sum()) == len(faces_w), f"{path.name}: face/UV bookkeeping mismatch after welding")
        uv = uv_all[faces[ok]].astype(np.float32)
    m = Material(str(mat.name) if isinstance(mat.name, str) and mat.name else f"material_{mi}",
                 tuple(float(x) for x in factor), float(np.clip(metallic, 0, 1)), float(np.clip(roughness, 0, 1)),
                 texture)
    return m, uv


def _read_image(gltf: Any, reader: _Reader, path: Path, tex_index: Any) -> np.ndarray | None:
    """RGB(A) uint8 pixels of texture ``tex_index`` (an image in a buffer view, PNG/JPEG), or ``None`` when the
    image is external or undecodable (the material then keeps only its factor)."""
    import cv2

    texs = gltf.textures or []
    if not (isinstance(tex_index, int) and 0 <= tex_index < len(texs)) or texs[tex_index].source is None:
        return None
    imgs = gltf.images or []
    src = texs[tex_index].source
    check(isinstance(src, int) and 0 <= src < len(imgs), f"{path.name}: texture {tex_index} image out of range")
    img = imgs[src]
    if img.bufferView is None:
        return None
    view = gltf.bufferViews[img.bufferView]
    data = reader.buffers[view.buffer]
    start = view.byteOffset or 0
    check(start + view.byteLength <= len(data), f"{path.name}: image {src} reads past the end of its buffer")
    raw = np.frombuffer(data, np.uint8, count=view.byteLength, offset=start)
    pix = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED)
    if pix is None or pix.dtype != np.uint8 or pix.ndim not in (2, 3):
        return None
    if pix.ndim == 2:
        pix = np.repeat(pix[..., None], 3, axis=2)
    return np.ascontiguousarray(pix[..., 2::-1] if pix.shape[2] >= 3 else np.repeat(pix[..., :1], 3, axis=2))
