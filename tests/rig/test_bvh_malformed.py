"""Malformed BVH files: every one ends in a single-line PrtError; a valid joint named ``*MOTION*`` loads.

A tiny BVH writer makes a valid file; a property-style generator mutates its tokens, lines and bytes.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prt_torch.errors import PrtError
from prt_torch.rig.bvh import load_bvh
from tests.rig.test_gltf_malformed import time_limit

#: (name, parent index, offset, channels) of the synthetic skeleton
JOINTS = [("Hips", -1, (0.0, 1.0, 0.0), ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]),
          ("Spine", 0, (0.0, 2.0, 0.5), ["Yrotation", "Xrotation", "Zrotation"]),
          ("Head", 1, (0.3, 1.5, 0.0), ["Xrotation", "Zrotation", "Yrotation"]),
          ("Leg", 0, (1.0, -1.0, 0.0), ["Zrotation", "Yrotation", "Xrotation"])]


def write_bvh(joints: list[tuple[str, int, tuple[float, float, float], list[str]]], data: np.ndarray,
              frame_time: float = 0.04) -> str:
    """BVH text of a skeleton (parents before children) and ``data (F, channels)``; leaves get an End Site."""
    lines = ["HIERARCHY"]

    def block(j: int, depth: int) -> None:
        name, parent, off, chans = joints[j]
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if parent < 0 else 'JOINT'} {name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {off[0]:g} {off[1]:g} {off[2]:g}")
        lines.append(f"{pad}  CHANNELS {len(chans)} {' '.join(chans)}")
        kids = [k for k, jt in enumerate(joints) if jt[1] == j]
        for k in kids:
            block(k, depth + 1)
        if not kids:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 1 0", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    block(0, 0)
    lines += ["MOTION", f"Frames: {data.shape[0]}", f"Frame Time: {frame_time:g}"]
    lines += [" ".join(f"{x:.4f}" for x in row) for row in data]
    return "\n".join(lines) + "\n"


def valid_text(frames: int = 3, joints: list | None = None) -> str:
    joints = JOINTS if joints is None else joints
    n = sum(len(j[3]) for j in joints)
    return write_bvh(joints, np.random.default_rng(0).uniform(-90, 90, size=(frames, n)))


def check_outcome(path: Path) -> None:
    """Load: a finite, shape-consistent result, or a one-line PrtError."""
    try:
        with time_limit():
            skel, clip = load_bvh(path)
    except PrtError as e:
        assert str(e) and "\n" not in str(e), repr(str(e))
        return
    j = len(skel.joint_names)
    assert skel.parents.shape == (j,) and np.all(skel.parents < np.arange(j))
    assert clip.local.shape[1:] == (j, 4, 4) and np.isfinite(clip.local).all()
    assert np.isfinite(skel.bind_local).all() and np.isfinite(clip.fps) and clip.fps > 0
    assert len(skel.channels) == j


TOKENS = ["nan", "inf", "-inf", "1e999", "-1", "0", "7", "{", "}", "MOTION", "HIERARCHY", "ROOT", "JOINT", "End",
          "Site", "OFFSET", "CHANNELS", "abc", "Xrotation", "Wrotation", "Frames:", "Frame", "Time:", "99999999999"]


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_mutated_bvh_loads_or_one_line_error(data: st.DataObject) -> None:
    text = valid_text()
    kind = data.draw(st.sampled_from(["token", "token", "line", "truncate", "bytes"]))
    if kind == "token":  # replace, insert or delete whitespace-separated tokens (keeping the layout)
        for _ in range(data.draw(st.integers(1, 3))):
            parts = text.split(" ")
            i = data.draw(st.integers(0, len(parts) - 1))
            op = data.draw(st.sampled_from(["replace", "insert", "delete"]))
            tok = data.draw(st.sampled_from(TOKENS))
            if op == "replace":
                parts[i] = tok + ("\n" if parts[i].endswith("\n") else "")
            elif op == "insert":
                parts.insert(i, tok)
            else:
                del parts[i]
            text = " ".join(parts)
    elif kind == "line":  # delete or duplicate a line
        lines = text.splitlines()
        i = data.draw(st.integers(0, len(lines) - 1))
        if data.draw(st.booleans()):
            del lines[i]
        else:
            lines.insert(i, lines[i])
        text = "\n".join(lines)
    elif kind == "truncate":
        text = text[:data.draw(st.integers(0, len(text) - 1))]
    else:
        raw = bytearray(text.encode())
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        text = raw.decode("latin-1")
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.bvh"
        p.write_text(text, encoding="latin-1")
        check_outcome(p)


@pytest.mark.parametrize("name", ["MOTION", "LeftMOTION", "MOTION_capture", "Frames:"])
def test_joint_named_motion_loads(tmp_path: Path, name: str) -> None:
    joints = [JOINTS[0], (name, 0, (0.0, 2.0, 0.0), ["Zrotation", "Xrotation", "Yrotation"])]
    p = tmp_path / "m.bvh"
    p.write_text(valid_text(4, joints))
    skel, clip = load_bvh(p)
    assert skel.joint_names == ["Hips", name] and clip.num_frames == 4
    assert skel.channels[1] == ["Zrotation", "Xrotation", "Yrotation"]


def _replace_row(text: str, row: int, new: str) -> str:
    lines = text.splitlines()
    start = lines.index("MOTION") + 3
    lines[start + row] = new
    return "\n".join(lines) + "\n"


GOOD = valid_text()
MOTION_AT = GOOD.index("MOTION")
NAMED = [
    ("truncated_hierarchy", GOOD[:MOTION_AT // 2], "truncated|expected"),
    ("truncated_motion", GOOD[:len(GOOD) - 40], "expected 3 frames|row 3 has"),
    ("nan", GOOD.replace(GOOD.splitlines()[-1].split()[2], "nan", 1), "NaN or inf"),
    ("inf_offset", GOOD.replace("OFFSET 0 2 0.5", "OFFSET 0 inf 0.5"), "OFFSET is not finite"),
    ("row_too_long", _replace_row(GOOD, 1, " ".join(["1"] * 16)), "row 2 has 16 values, expected 15"),
    ("row_split", _replace_row(_replace_row(GOOD, 0, "1 2 3"), 1, "4 5"), "row 1 has 3 values"),
    ("unknown_channel", GOOD.replace("Yrotation Xrotation Zrotation", "Yrotation Xrotation Qrotation"),
     "unknown BVH channel 'Qrotation'"),
    ("repeated_channel", GOOD.replace("Yrotation Xrotation Zrotation", "Yrotation Yrotation Zrotation"),
     "repeats a channel"),
    ("channel_count", GOOD.replace("CHANNELS 3 Yrotation", "CHANNELS 9 Yrotation"), "bad channel count"),
    ("no_frames", GOOD.replace("Frames: 3\n", ""), "missing 'Frames:'"),
    ("no_frame_time", GOOD.replace("Frame Time: 0.04\n", ""), "missing 'Frame Time:'"),
    ("frame_time_zero", GOOD.replace("Frame Time: 0.04", "Frame Time: 0"), "Frame Time must be > 0"),
    ("frame_time_negative", GOOD.replace("Frame Time: 0.04", "Frame Time: -0.04"), "Frame Time must be > 0"),
    ("frame_time_nan", GOOD.replace("Frame Time: 0.04", "Frame Time: nan"), "Frame Time is not finite"),
    ("frame_time_tiny", GOOD.replace("Frame Time: 0.04", "Frame Time: 1e-320"), "too small"),
    ("frames_mismatch", GOOD.replace("Frames: 3", "Frames: 5"), "expected 5 frames, found 3"),
    ("frames_bad", GOOD.replace("Frames: 3", "Frames: three"), "bad frame count"),
    ("extra_close", GOOD.replace("MOTION", "}\nMOTION"), "unbalanced braces"),
    ("missing_close", GOOD.replace("}\nMOTION", "MOTION"), "unexpected token 'MOTION'"),
    ("empty_hierarchy", "HIERARCHY\nMOTION\nFrames: 1\nFrame Time: 0.1\n\n", "empty BVH hierarchy"),
    ("no_motion", GOOD[:MOTION_AT], "not a BVH file"),
    ("joint_outside_root", GOOD.replace("ROOT Hips", "JOINT Hips"), "JOINT outside"),
    ("empty_file", "", "not a BVH file"),
]


@pytest.mark.parametrize("case, text, match", NAMED, ids=[c[0] for c in NAMED])
def test_named_malformed_bvh(tmp_path: Path, case: str, text: str, match: str) -> None:
    p = tmp_path / f"{case}.bvh"
    p.write_text(text)
    with time_limit(), pytest.raises(PrtError, match=match) as e:
        load_bvh(p)
    assert "\n" not in str(e.value)


def test_valid_writer_round_trip(tmp_path: Path) -> None:
    p = tmp_path / "ok.bvh"
    p.write_text(valid_text(5))
    skel, clip = load_bvh(p)
    assert skel.joint_names == [j[0] for j in JOINTS] and clip.num_frames == 5
    assert clip.fps == pytest.approx(25.0) and math.isfinite(float(clip.local.sum()))
