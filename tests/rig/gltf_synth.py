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
