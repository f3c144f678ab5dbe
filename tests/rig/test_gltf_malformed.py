"""Malformed glTF/GLB files: every one ends in a single-line PrtError (never another exception, a hang or garbage).

A property-style generator starts from the valid synthetic rig of ``test_gltf.write_rig`` and mutates its JSON
values (out-of-range indices, wrong types, NaN, huge numbers, deleted keys), its node graph (cycles, two parents),
its buffer views (stride shrink) and the GLB bytes (truncation, byte flips, header lengths); named cases follow.
"""

from __future__ import annotations

import copy
import math
import signal
import struct
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rig.gltf import MAX_CLIP_BYTES, load_gltf
from tests.rig.gltf_synth import glb_bytes, split_document, write_document
from tests.rig.test_gltf import write_rig

TIME_LIMIT_S = 10


@contextmanager
def time_limit(seconds: int = TIME_LIMIT_S) -> Iterator[None]:
    """Fail (TimeoutError) instead of hanging: SIGALRM after ``seconds``."""
    def handler(signum: int, frame: Any) -> None:
        raise TimeoutError(f"the loader ran for more than {seconds} s (a hang?)")

    old = signal.signal(signal.SIGALRM, handler)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], bytes]:
    """The valid synthetic rig as ``(JSON document, buffer bytes)``."""
    return split_document(write_rig(tmp_path_factory.mktemp("base") / "rig.gltf"))


def check_outcome(path: Path) -> Character | None:
    """Load ``path``: a character with finite, consistent arrays, or a one-line PrtError (returns None)."""
    try:
        with time_limit():
            c = load_gltf(path)
    except PrtError as e:
        msg = str(e)
        assert msg and "\n" not in msg and "\r" not in msg, repr(msg)
        return None
    v = c.num_vertices
    assert c.rest_vertices.shape == (v, 3) and np.isfinite(c.rest_vertices).all()
    assert c.rest_normals.shape == (v, 3) and np.isfinite(c.rest_normals).all()
    assert c.faces.ndim == 2 and c.faces.shape[1] == 3 and ((c.faces >= 0) & (c.faces < v)).all()
    assert c.weights.shape == c.joints.shape and np.isfinite(c.weights).all()
    assert np.isfinite(c.bind_local).all() and np.isfinite(c.inverse_bind).all()
    for clip in c.clips.values():
        assert clip.local.shape[1:] == (c.num_joints, 4, 4) and np.isfinite(clip.local).all()
    return c


def value_paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Paths (keys / indices) to every number and list in the document, buffers' uri excluded."""
    out: list[tuple] = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            if k != "uri":
                out += value_paths(v, prefix + (k,))
    elif isinstance(doc, list):
        out.append(prefix)
        for i, v in enumerate(doc):
            out += value_paths(v, prefix + (i,))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
        out.append(prefix)
    return out


def set_path(doc: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        doc = doc[k]
    if value is _DELETE:
        del doc[path[-1]]
    else:
        doc[path[-1]] = value


_DELETE = object()
REPLACEMENTS = [-1, 0, 1, 2, 3, 7, 64, 2**31, 2**63, -(2**31), 3.5, math.nan, math.inf, -math.inf, 1e308, -1e308,
                "x", None, True, [], [0], [1, 2], {}, _DELETE]
ROOT_NODE, JOINT_NODES = 0, (3, 4)


def mutate_json(doc: dict[str, Any], data: st.DataObject) -> dict[str, Any]:
    doc = copy.deepcopy(doc)
    kind = data.draw(st.sampled_from(["value", "value", "value", "cycle", "two_parents", "stride", "trs"]))
    if kind == "value":
        paths = value_paths(doc)
        for _ in range(data.draw(st.integers(1, 3))):
            path = data.draw(st.sampled_from(paths))
            if path:
                value = data.draw(st.sampled_from(REPLACEMENTS))
                set_path(doc, path, value if value is _DELETE else copy.deepcopy(value))
                paths = value_paths(doc)
    elif kind == "cycle":  # a node lists one of its ancestors (or itself) as a child
        n = data.draw(st.sampled_from([2, 3, 4]))
        doc["nodes"][n].setdefault("children", []).append(data.draw(st.sampled_from([0, 2, 3, n])))
    elif kind == "two_parents":
        doc["nodes"][1].setdefault("children", []).append(data.draw(st.sampled_from([2, 3, 4])))
    elif kind == "stride":
        view = data.draw(st.integers(0, len(doc["bufferViews"]) - 1))
        doc["bufferViews"][view]["byteStride"] = data.draw(st.sampled_from([1, 2, 4, 8, 12, 252, 256]))
    else:  # node matrix / TRS of the wrong length or with NaN
        node = data.draw(st.integers(0, len(doc["nodes"]) - 1))
        key, n = data.draw(st.sampled_from([("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)]))
        length = data.draw(st.sampled_from([0, n - 1, n, n + 1]))
        vals = [data.draw(st.sampled_from([0.0, 1.0, math.nan, 1e308])) for _ in range(length)]
        doc["nodes"][node][key] = vals
        if key == "matrix":
            for k in ("translation", "rotation", "scale"):
                doc["nodes"][node].pop(k, None)
    return doc


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data(), suffix=st.sampled_from([".glb", ".gltf"]))
def test_mutated_json_loads_or_one_line_error(base: tuple[dict[str, Any], bytes], data: st.DataObject,
                                              suffix: str) -> None:
    doc = mutate_json(base[0], data)
    with tempfile.TemporaryDirectory() as d:
        check_outcome(write_document(Path(d) / f"m{suffix}", doc, base[1]))


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_mutated_glb_bytes_load_or_one_line_error(base: tuple[dict[str, Any], bytes], data: st.DataObject) -> None:
    raw = bytearray(glb_bytes(base[0], base[1]))
    kind = data.draw(st.sampled_from(["truncate", "flip", "flip", "header"]))
    if kind == "truncate":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    elif kind == "flip":  # bytes anywhere: JSON text (values, syntax) or binary data (NaN floats, indices)
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, len(raw) - 1))
            raw[i] = data.draw(st.integers(0, 255))
    else:  # GLB version / total length / chunk lengths
        field = data.draw(st.sampled_from([4, 8, 12, 20 + struct.unpack_from("<I", raw, 12)[0]]))
        struct.pack_into("<I", raw, field, data.draw(st.sampled_from([0, 1, 3, 2**31, 2**32 - 1, len(raw) + 8])))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.glb"
        p.write_bytes(bytes(raw))
        check_outcome(p)


def test_unmutated_base_loads(base: tuple[dict[str, Any], bytes], tmp_path: Path) -> None:
    for suffix in (".glb", ".gltf"):
        assert check_outcome(write_document(tmp_path / f"ok{suffix}", base[0], base[1])) is not None


def _edit(doc: dict[str, Any], edit: str) -> None:
    exec(edit, {"math": math}, {"d": doc})  # noqa: S102 - test-local table of edits


NAMED = [
    ("cycle", "d['nodes'][2]['children'] = []; d['nodes'][4]['children'] = [3]", "cycle through node"),
    ("cycle_through_root", "d['nodes'][4]['children'] = [0]", "cycle|two parents"),
    ("self_child", "d['nodes'][2]['children'] = [2, 3]", "itself"),
    ("two_parents", "d['nodes'][1]['children'] = [3]", "two parents"),
    ("mesh_index", "d['nodes'][1]['mesh'] = 5", "node 1 mesh = 5 is out of range"),
    ("skin_index", "d['nodes'][1]['skin'] = 9", "node 1 skin = 9 is out of range"),
    ("sampler_index", "d['animations'][0]['channels'][0]['sampler'] = 7", "sampler = 7 is out of range"),
    ("child_index", "d['nodes'][0]['children'] = [1, 99]", "child = 99 is out of range"),
    ("bufferview_index", "d['accessors'][0]['bufferView'] = 400", "bufferView = 400 is out of range"),
    ("accessor_index", "d['meshes'][0]['primitives'][0]['attributes']['POSITION'] = 999", "POSITION = 999 is out"),
    ("buffer_index", "d['bufferViews'][0]['buffer'] = 3", "buffer = 3 is out of range"),
    ("negative_index", "d['nodes'][0]['children'] = [-1]", "out of range"),
    ("count_zero", "d['accessors'][0]['count'] = 0", "count = 0 is out of range"),
    ("count_huge", "d['accessors'][0]['count'] = 10**12", "GiB|need"),
    ("stride_too_small", "d['bufferViews'][0]['byteStride'] = 4", "smaller than the element size 12"),
    ("view_past_buffer", "d['bufferViews'][0]['byteLength'] = 10**6", "runs past the end of buffer"),
    ("accessor_past_view", "d['accessors'][0]['byteOffset'] = 8", "need .* bytes but bufferView"),
    ("short_matrix", "d['nodes'][0]['matrix'] = d['nodes'][0]['matrix'][:12]", "matrix has 12 numbers, expected 16"),
    ("long_translation", "d['nodes'][2]['translation'] = [0, 0, 0, 1]", "translation has 4 numbers, expected 3"),
    ("short_rotation", "d['nodes'][2]['rotation'] = [0, 0, 1]", "rotation has 3 numbers, expected 4"),
    ("zero_rotation", "d['nodes'][2]['rotation'] = [0, 0, 0, 0]", "zero quaternion"),
    ("nan_translation", "d['nodes'][3]['translation'] = [math.nan, 0, 0]", "NaN or inf"),
    ("string_index", "d['nodes'][1]['mesh'] = 'zero'", "cannot parse|integer"),
    ("unknown_component", "d['accessors'][0]['componentType'] = 5130", "componentType"),
    ("joints_as_float", "d['meshes'][0]['primitives'][0]['attributes']['JOINTS_0'] = 0", "JOINTS_0: accessor 0"),
    ("attribute_counts", "d['meshes'][0]['primitives'][0]['attributes']['WEIGHTS_0'] = 7", "different counts|WEIGHTS"),
    ("ibm_count", "d['accessors'][d['skins'][0]['inverseBindMatrices']]['count'] = 1", "inverse bind matrices"),
    ("anim_output_shape", "d['animations'][0]['samplers'][0]['output'] = d['animations'][0]['samplers'][1]['output']",
     "sampler output is"),
    ("interpolation", "d['animations'][0]['samplers'][0]['interpolation'] = 'SMOOTH'", "unknown interpolation"),
    ("duplicate_joint", "d['skins'][0]['joints'] = [3, 3]", "joint node twice"),
]


@pytest.mark.parametrize("case, edit, match", NAMED, ids=[c[0] for c in NAMED])
@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_named_malformed_json(base: tuple[dict[str, Any], bytes], tmp_path: Path, case: str, edit: str, match: str,
                              suffix: str) -> None:
    doc = copy.deepcopy(base[0])
    _edit(doc, edit)
    p = write_document(tmp_path / f"{case}{suffix}", doc, base[1])
    with time_limit(), pytest.raises(PrtError, match=match) as e:
        load_gltf(p)
    assert "\n" not in str(e.value)


def test_bad_base64_and_truncated_buffers(base: tuple[dict[str, Any], bytes], tmp_path: Path) -> None:
    p = write_document(tmp_path / "b.gltf", base[0], base[1])
    text = p.read_text()
    bad = tmp_path / "bad64.gltf"
    bad.write_text(text.replace(";base64,", ";base64,@@"))
    with pytest.raises(PrtError, match="bad base64 data URI"):
        load_gltf(bad)
    doc = copy.deepcopy(base[0])
    doc["buffers"][0]["byteLength"] += 64
    with pytest.raises(PrtError, match="shorter than its byteLength"):
        load_gltf(write_document(tmp_path / "short.gltf", doc, base[1]))
    with pytest.raises(PrtError, match="shorter than its byteLength"):
        load_gltf(write_document(tmp_path / "short.glb", doc, base[1]))


def test_glb_header_and_chunks(base: tuple[dict[str, Any], bytes], tmp_path: Path) -> None:
    raw = glb_bytes(base[0], base[1])
    cases = {
        "version": (raw[:4] + struct.pack("<I", 1) + raw[8:], "GLB container version 1"),
        "length": (raw[:8] + struct.pack("<I", len(raw) + 100) + raw[12:], "truncated"),
        "chunk": (raw[:12] + struct.pack("<I", 2**31) + raw[16:], "runs past the end of the file"),
        "cut": (raw[:len(raw) - 40], "the GLB header says"),
        "magic": (b"xxxx" + raw[4:], "bad GLB magic"),
        "tiny": (raw[:7], "truncated GLB header|bad GLB magic"),
    }
    for name, (data, match) in cases.items():
        p = tmp_path / f"{name}.glb"
        p.write_bytes(data)
        with pytest.raises(PrtError, match=match):
            load_gltf(p)


def test_clip_frame_bound(base: tuple[dict[str, Any], bytes], tmp_path: Path) -> None:
    """Key times of 1e9 s would sample 3e10 frames: refused with the estimate instead of allocating."""
    doc = copy.deepcopy(base[0])
    blob = bytearray(base[1])
    acc = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    view = doc["bufferViews"][acc["bufferView"]]
    start = view["byteOffset"] + acc.get("byteOffset", 0)
    struct.pack_into("<f", blob, start + 4 * (acc["count"] - 1), 1e9)
    p = write_document(tmp_path / "long.glb", doc, bytes(blob))
    with time_limit(), pytest.raises(PrtError, match=f"GiB of joint transforms exceeds the {MAX_CLIP_BYTES >> 30} GiB"):
        load_gltf(p)


def test_cli_info_bad_glb_is_one_error_line(base: tuple[dict[str, Any], bytes], tmp_path: Path) -> None:
    doc = copy.deepcopy(base[0])
    doc["nodes"][2]["children"] = []
    doc["nodes"][4]["children"] = [3]  # a cycle 3 -> 4 -> 3: the old loader looped forever
    p = write_document(tmp_path / "BAD.glb", doc, base[1])
    r = subprocess.run([sys.executable, "-m", "prt_torch", "info", str(p)], capture_output=True, text=True,
                       timeout=120, cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "cycle" in lines[0], r.stderr
