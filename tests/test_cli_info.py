"""``prt info``: JSON of the built-in humanoid, a synthetic glTF (unnamed animation, materials), a BVH and
the shared Fox; tables; one-line errors with exit status 2; no torch."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from prt_torch.cli import main
from prt_torch.rig.builtin import CLIP_NAMES, JOINT_NAMES, make_character
from prt_torch.rig.gltf import load_gltf
from tests.rig.test_gltf import write_renamed_rig

REPO = Path(__file__).resolve().parents[1]

MATERIALS = [
    {"name": "skin", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.5, 0.25, 1.0], "roughnessFactor": 0.4,
                                              "metallicFactor": 0.0}},
    {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},  # unnamed, unused, spec defaults
]

BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Knee
  {
    OFFSET 0 -1 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -1 0
    }
  }
}
MOTION
Frames: 4
Frame Time: 0.04
0 1 0 0 0 0 10 0 0
0 1 0 0 0 0 20 0 0
0 1 0 0 0 0 30 0 0
0 1 0 0 0 0 40 0 0
"""


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    code, out, err = _run(capsys, "info", *argv, "--json")
    assert code == 0, err
    return json.loads(out)


def write_synthetic(tmp_path: Path) -> Path:
    """The rig of tests/rig/test_gltf.py with an unnamed 1 s animation, a named 0.8 s one and two materials."""
    path = write_renamed_rig(tmp_path / "synth", [("lin", None), ("step", "Walk")])
    doc = json.loads(path.read_text())
    doc["materials"] = MATERIALS
    doc["textures"] = [{"source": 0}]
    doc["images"] = [{"uri": "skin.png"}]
    for prim in doc["meshes"][0]["primitives"]:
        prim["material"] = 0
    path.write_text(json.dumps(doc))
    return path


def test_builtin(capsys: pytest.CaptureFixture[str]) -> None:
    obj = _json(capsys, "builtin")
    ref = make_character()
    assert obj["kind"] == "builtin" and obj["character"] == ref.name
    assert (obj["vertices"], obj["faces"]) == (ref.num_vertices, len(ref.faces)) == (11730, 23456)
    assert [j["name"] for j in obj["joints"]] == list(JOINT_NAMES)
    assert obj["joints"][0]["parent"] is None and obj["joints"][0]["parent_index"] == -1
    for j in obj["joints"][1:]:
        assert j["parent"] == JOINT_NAMES[j["parent_index"]] and j["parent_index"] < j["index"]
    assert [c["name"] for c in obj["clips"]] == list(CLIP_NAMES)
    for c in obj["clips"]:
        assert c["frames"] == ref.clips[c["name"]].num_frames and c["fps"] == 30.0
        assert c["duration"] == pytest.approx((c["frames"] - 1) / 30.0)
    assert obj["materials"] == [] and 1.7 < obj["height"] < 1.9


def test_synthetic_gltf_unnamed_animation_and_materials(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_synthetic(tmp_path)
    obj = _json(capsys, str(path))
    assert obj["kind"] == "gltf" and obj["character"] == "synth" and obj["vertices"] == 9
    assert [(j["name"], j["parent"]) for j in obj["joints"]] == [("j0", None), ("j1", "j0")]
    # the documented name of the unnamed animation 0, with its frame count: keys span 1 s -> 31 frames at 30 fps
    assert obj["clips"] == [{"name": "animation_0", "frames": 31, "fps": 30.0, "duration": 1.0},
                            {"name": "Walk", "frames": 25, "fps": 30.0, "duration": pytest.approx(0.8)}]
    assert load_gltf(path).pose("animation_0").num_frames == 31  # the name shown is the name that works
    assert obj["materials"] == [
        {"index": 0, "name": "skin", "base_color_factor": [0.8, 0.5, 0.25, 1.0], "base_color_texture": False,
         "roughness_factor": 0.4, "metallic_factor": 0.0, "used": True},
        {"index": 1, "name": None, "base_color_factor": [1.0, 1.0, 1.0, 1.0], "base_color_texture": True,
         "roughness_factor": 1.0, "metallic_factor": 1.0, "used": False},
    ]
    slow = _json(capsys, str(path), "--fps", "10")
    assert [(c["name"], c["frames"], c["fps"]) for c in slow["clips"]] == [("animation_0", 11, 10.0), ("Walk", 9, 10.0)]


def test_tables(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _run(capsys, "info", str(write_synthetic(tmp_path)))
    assert code == 0, err
    for word in ("animation_0", "Walk", "31", "j0", "j1", "skin", "(unnamed)", "materials", "clips"):
        assert word in out
    (tmp_path / "m.bvh").write_text(BVH)
    code, out, err = _run(capsys, "info", str(tmp_path / "m.bvh"))
    assert code == 0, err
    assert "pos XYZ rot ZYX" in out and "rot ZXY" in out and "Knee" in out


def test_bvh(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "m.bvh").write_text(BVH)
    obj = _json(capsys, str(tmp_path / "m.bvh"))
    assert obj["kind"] == "bvh" and obj["materials"] == [] and obj["height"] is None
    assert [(j["name"], j["parent"], j["channels"]) for j in obj["joints"]] == [
        ("Hips", None, ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]),
        ("Knee", "Hips", ["Zrotation", "Xrotation", "Yrotation"])]
    assert obj["clips"] == [{"name": "m", "frames": 4, "fps": pytest.approx(25.0), "duration": pytest.approx(0.12)}]


def test_fox(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    obj = _json(capsys, str(shared_data / "characters" / "Fox.glb"))
    assert obj["character"] == "Fox" and len(obj["joints"]) == 24
    assert [(c["name"], c["frames"]) for c in obj["clips"]] == [("Survey", 103), ("Walk", 22), ("Run", 35)]
    assert [(m["name"], m["base_color_texture"], m["used"]) for m in obj["materials"]] == [("fox_material", True, True)]
    assert obj["materials"][0]["roughness_factor"] == pytest.approx(0.58)


def test_shared_unnamed_and_bvh(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fig = _json(capsys, str(shared_data / "characters" / "RiggedFigure.glb"))
    assert [c["name"] for c in fig["clips"]] == ["animation_0"]  # its one animation has no name
    mocap = _json(capsys, str(shared_data / "motion" / "131_01.bvh"))
    assert mocap["joints"][0]["channels"][:3] == ["Xposition", "Yposition", "Zposition"]
    assert len(mocap["clips"]) == 1 and mocap["clips"][0]["frames"] > 100


@pytest.mark.parametrize("name, content, match", [
    ("missing.glb", None, "file not found: "),
    ("mesh.obj", "v 0 0 0\n", "unknown file type '.obj'"),
    ("noext", "x", "unknown file type '(none)'"),
    ("junk.glb", "not a glb at all" * 8, "junk.glb"),
    ("junk.gltf", "{not json", "cannot parse glTF"),
    ("list.gltf", "[1, 2]", "list.gltf"),
    ("empty.gltf", '{"asset": {"version": "2.0"}}', "has no nodes"),
    ("badjoint.gltf", '{"asset": {"version": "2.0"}, "nodes": [{"mesh": 0, "skin": 0}], "skins": [{"joints": [5]}], '
                      '"meshes": []}', "out of range"),
    ("junk.bvh", "hello", "not a BVH file"),
    ("short.bvh", BVH.replace("Frames: 4", "Frames: 5"), "expected 5 frames"),
    ("dir", "DIR", "not a file"),
])
def test_bad_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, content: str | None,
                    match: str) -> None:
    path = tmp_path / name
    if content == "DIR":
        path.mkdir()
    elif content is not None:
        path.write_text(content)
    code, out, err = _run(capsys, "info", str(path), "--json")
    assert code == 2 and out == ""
    assert err.startswith("error: ") and err.count("\n") == 1 and match in err, err


def test_bad_fps(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(capsys, "info", "builtin", "--fps", "0")
    assert code == 2 and err.startswith("error: --fps must be > 0") and err.count("\n") == 1


def test_subprocess_exit_status_and_no_torch(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "prt_torch", "info", str(tmp_path / "missing.gltf")],
                       capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [f"error: file not found: {tmp_path / 'missing.gltf'}"]
    path = write_synthetic(tmp_path)
    code = (f"import json, sys\nfrom prt_torch.cli import main\nassert main(['info', {str(path)!r}, '--json']) == 0\n"
            "print(json.dumps('torch' in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert json.loads(lines[0])["clips"][0]["name"] == "animation_0"
    assert json.loads(lines[-1]) is False
