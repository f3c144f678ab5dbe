"""A tiny synthetic skinned glTF writer for the rig tests (independent of the loader under test)."""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

CTYPE = {np.dtype(np.float32): 5126, np.dtype(np.uint16): 5123, np.dtype(np.uint8): 5121, np.dtype(np.uint32): 5125}
TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}


class GltfBuilder:
    """Collects JSON + one binary buffer; ``write(path)`` produces ``.glb`` or ``.gltf`` (data URI)."""

    def __init__(self) -> None:
        self.doc: dict[str, Any] = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": []}], "nodes": [],
                                    "meshes": [], "accessors": [], "bufferViews": [], "buffers": []}
        self.blob = bytearray()

    def accessor(self, arr: np.ndarray, normalized: bool = False) -> int:
        arr = np.ascontiguousarray(arr)
        ncomp = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": arr.nbytes})
        self.blob += arr.tobytes()
        acc = {"bufferView": len(self.doc["bufferViews"]) - 1, "componentType": CTYPE[arr.dtype],
               "count": int(arr.shape[0]), "type": TYPE[ncomp]}
        if normalized:
            acc["normalized"] = True
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def node(self, **kw: Any) -> int:
        self.doc["nodes"].append(kw)
        return len(self.doc["nodes"]) - 1

    def write(self, path: Path) -> Path:
        doc = json.loads(json.dumps(self.doc))
        for k in ("meshes", "accessors", "bufferViews"):
            if not doc[k]:
                del doc[k]
        if path.suffix == ".gltf":
            uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.blob)).decode()
            doc["buffers"] = [{"byteLength": len(self.blob), "uri": uri}]
            path.write_text(json.dumps(doc))
            return path
        doc["buffers"] = [{"byteLength": len(self.blob)}]
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        bn = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        total = 12 + 8 + len(js) + 8 + len(bn)
        out = struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
        out += struct.pack("<II", len(bn), 0x004E4942) + bn
        path.write_bytes(out)
        return path


def glb_bytes(doc: dict[str, Any], blob: bytes) -> bytes:
    """A ``.glb`` container of a JSON document and one binary chunk (buffer 0 must have no ``uri``)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    bn = bytes(blob) + b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(js) + 8 + len(bn)
    out = struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
    return out + struct.pack("<II", len(bn), 0x004E4942) + bn


def split_document(path: Path) -> tuple[dict[str, Any], bytes]:
    """``(JSON document, buffer 0 bytes)`` of a ``.gltf`` file whose single buffer is a base64 data URI."""
    doc = json.loads(path.read_text())
    uri = doc["buffers"][0].pop("uri")
    return doc, base64.b64decode(uri.split(",", 1)[1])


def write_document(path: Path, doc: dict[str, Any], blob: bytes) -> Path:
    """Write ``doc`` + ``blob`` (buffer 0) as ``.glb`` or, for a ``.gltf`` path, with a base64 data URI."""
    doc = json.loads(json.dumps(doc, allow_nan=True))
    if path.suffix == ".gltf":
        if doc.get("buffers"):
            doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        path.write_text(json.dumps(doc))
    else:
        path.write_bytes(glb_bytes(doc, blob))
    return path


def _tube(base: np.ndarray, axis: np.ndarray, u: np.ndarray, length: float, radius: float, rings: int,
          segments: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube: ``rings x segments`` side vertices from ``base`` along the unit ``axis`` (``u`` and
    ``axis x u`` span its cross-section), then the bottom and top cap centres; faces counter-clockwise from outside."""
    v = np.cross(axis, u)  # u x v = axis: the angle runs counter-clockwise about the axis
    th = 2 * np.pi * np.arange(segments) / segments
    ring = radius * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v)
    side = np.concatenate([base + axis * (length * k / (rings - 1)) + ring for k in range(rings)])
    pos = np.concatenate([side, [base, base + axis * length]])
    faces = []
    for k in range(rings - 1):
        for i in range(segments):
            a, b = k * segments + i, k * segments + (i + 1) % segments
            faces += [[a, b, b + segments], [a, b + segments, a + segments]]
    bottom, top, last = len(side), len(side) + 1, (rings - 1) * segments
    for i in range(segments):
        faces += [[bottom, (i + 1) % segments, i], [top, last + i, last + (i + 1) % segments]]
    return pos, np.asarray(faces)


#: the figure's animations: name -> (joint index, axis, degrees at FIGURE_TIMES) per animated joint
FIGURE_ANIMATIONS: dict[str, list[tuple[int, tuple[float, float, float], list[float]]]] = {
    "bend": [(1, (0.0, 0.0, 1.0), [0.0, 25.0, -25.0, 0.0]), (2, (0.0, 0.0, 1.0), [0.0, 30.0, 60.0, 0.0])],
    "lift": [(2, (0.0, 0.0, 1.0), [0.0, 70.0, 20.0, 50.0]), (1, (1.0, 0.0, 0.0), [0.0, 15.0, 0.0, -10.0])],
    "twist": [(1, (0.0, 1.0, 0.0), [0.0, 40.0, -40.0, 0.0]), (2, (0.0, 0.0, 1.0), [0.0, 45.0, 45.0, 10.0])],
}
FIGURE_TIMES = np.array([0.0, 0.5, 1.0, 1.5])
#: the figure's material: linear base colour factor, metallic, roughness
FIGURE_MATERIAL = ((0.9, 0.45, 0.25, 1.0), 0.0, 0.6)


def write_figure(path: Path) -> Path:
    """A small skinned figure with a material (:data:`FIGURE_MATERIAL`): a body tube 1.6 tall (joints ``root`` and
    ``spine`` at 0 and 0.8, blended over 0.6..1.0) and an arm tube out of its side (joint ``arm``), 134 vertices,
    y-up like every glTF file; animations :data:`FIGURE_ANIMATIONS` (LINEAR, 1.5 s)."""
    body, body_f = _tube(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 1.6, 0.18, 9, 10)
    arm, arm_f = _tube(np.array([0.18, 1.25, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 0.6, 0.07,
                       5, 8)
    pos = np.concatenate([body, arm])
    faces = np.concatenate([body_f, arm_f + len(body)])
    w_spine = np.clip((body[:, 1] - 0.6) / 0.4, 0.0, 1.0)
    w_arm = np.clip((arm[:, 0] - 0.18) / 0.15, 0.0, 1.0)
    weights = np.zeros((len(pos), 4))
    weights[:len(body), 0], weights[:len(body), 1] = 1 - w_spine, w_spine
    weights[len(body):, 1], weights[len(body):, 2] = 1 - w_arm, w_arm
    b = GltfBuilder()
    factor, metallic, roughness = FIGURE_MATERIAL
    b.doc["materials"] = [{"name": "clay", "pbrMetallicRoughness": {
        "baseColorFactor": list(factor), "metallicFactor": metallic, "roughnessFactor": roughness}}]
    b.doc["meshes"].append({"primitives": [{"attributes": {
        "POSITION": b.accessor(pos.astype(np.float32)),
        "JOINTS_0": b.accessor(np.tile(np.array([0, 1, 2, 0], np.uint8), (len(pos), 1))),
        "WEIGHTS_0": b.accessor(weights.astype(np.float32))},
        "indices": b.accessor(faces.reshape(-1).astype(np.uint16)), "material": 0, "mode": 4}]})
    rest = np.array([[0.0, 0.0, 0.0], [0.0, 0.8, 0.0], [0.18, 1.25, 0.0]])  # joint rest positions (world)
    b.node(name="root", translation=rest[0].tolist(), children=[1])
    b.node(name="spine", translation=(rest[1] - rest[0]).tolist(), children=[2])
    b.node(name="arm", translation=(rest[2] - rest[1]).tolist())
    mesh = b.node(name="figure", mesh=0, skin=0)
    b.doc["scenes"][0]["nodes"] = [0, mesh]
    ibm = np.tile(np.eye(4), (3, 1, 1))
    ibm[:, :3, 3] = -rest
    b.doc["skins"] = [{"joints": [0, 1, 2], "inverseBindMatrices": b.accessor(
        ibm.transpose(0, 2, 1).reshape(3, 16).astype(np.float32))}]
    anims = []
    for name, channels in FIGURE_ANIMATIONS.items():
        times = b.accessor(FIGURE_TIMES.astype(np.float32))
        samplers, targets = [], []
        for k, (joint, axis, degs) in enumerate(channels):
            half = np.radians(np.asarray(degs))[:, None] / 2
            q = np.concatenate([np.asarray(axis)[None] * np.sin(half), np.cos(half)], axis=1)
            samplers.append({"input": times, "output": b.accessor(q.astype(np.float32)), "interpolation": "LINEAR"})
            targets.append({"sampler": k, "target": {"node": joint, "path": "rotation"}})
        anims.append({"name": name, "samplers": samplers, "channels": targets})
    b.doc["animations"] = anims
    return b.write(path)
