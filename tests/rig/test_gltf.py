"""glTF loading: synthetic rigs against an independent reference, and the shared assets."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation, Slerp

from prt_torch.errors import PrtError, PrtWarning
from prt_torch.rig.gltf import clip_names, load_gltf
from tests.rig.gltf_synth import GltfBuilder

C = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])  # y-up -> z-up
MROOT = np.array([[1.0, 0, 0, 0.5], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # z-up mesh -> y-up world


def trs(t=(0, 0, 0), q=(0, 0, 0, 1)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix()
    m[:3, 3] = t
    return m


ARM_T, ARM_Q = (0.1, 0.0, 0.2), Rotation.from_euler("y", 30, degrees=True).as_quat()
J0_T, J0_Q = (0.0, 0.0, 0.0), Rotation.from_euler("x", 10, degrees=True).as_quat()
J1_T, J1_Q = (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0)


def prism_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed triangular prism along +z in 2 segments: positions (9, 3), weights (9, 2), faces."""
    ang = np.radians([90, 210, 330])
    ring = np.stack([0.2 * np.cos(ang), 0.2 * np.sin(ang), np.zeros(3)], 1)
    pos = np.concatenate([ring + [0, 0, z] for z in (0.0, 1.0, 2.0)])
    w1 = np.repeat([0.0, 0.5, 1.0], 3)
    weights = np.stack([1 - w1, w1], 1)
    faces = []
    for r in range(2):
        for i in range(3):
            a, b = 3 * r + i, 3 * r + (i + 1) % 3
            faces += [[a, b, b + 3], [a, b + 3, a + 3]]
    faces += [[0, 2, 1], [6, 7, 8]]
    return pos, weights, np.array(faces)


ANIMS = {
    "lin": ("LINEAR", np.array([0.0, 0.5, 1.0]), [0.0, 60.0, 150.0]),
    "step": ("STEP", np.array([0.0, 0.4, 0.8]), [0.0, 45.0, -30.0]),
    "cubic": ("CUBICSPLINE", np.array([0.0, 0.6, 1.2]), [0.0, 70.0, 20.0]),
}
TANGENT_SCALE = 0.3


def cubic_tangents(n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    return TANGENT_SCALE * rng.normal(size=(n, 4)), TANGENT_SCALE * rng.normal(size=(n, 4))


def write_rig(path: Path, *, skin: bool = True, nan: bool = False, weight_scale: float = 1.0,
              stray: float | None = None) -> Path:
    """The synthetic two-joint prism rig (``nan``: a NaN vertex coordinate; ``stray``: vertex 4 moved to this x)."""
    pos, weights, faces = prism_mesh()
    if nan:
        pos = pos.copy()
        pos[4, 1] = np.nan
    if stray is not None:
        pos = pos.copy()
        pos[4, 0] = stray
    b = GltfBuilder()
    # primitive A: the lower two rings, indexed; primitive B: rings 1-2 non-indexed (duplicates to weld)
    fa = faces[[f for f in range(len(faces)) if faces[f].max() <= 5]]
    fb = faces[[f for f in range(len(faces)) if faces[f].min() >= 3]]
    prims = []
    va = np.arange(6)
    prim_a = {"POSITION": b.accessor(pos[va].astype(np.float32))}
    if skin:
        prim_a["JOINTS_0"] = b.accessor(np.tile(np.array([0, 1, 0, 0], np.uint16), (6, 1)))
        prim_a["WEIGHTS_0"] = b.accessor(np.c_[weights[va] * weight_scale, np.zeros((6, 2))].astype(np.float32))
    prims.append({"attributes": prim_a, "indices": b.accessor(fa.reshape(-1).astype(np.uint16)), "mode": 4})
    flat = fb.reshape(-1)
    prim_b = {"POSITION": b.accessor(pos[flat].astype(np.float32))}
    if skin:
        prim_b["JOINTS_0"] = b.accessor(np.tile(np.array([0, 1, 0, 0], np.uint8), (len(flat), 1)))
        wb = np.c_[weights[flat], np.zeros((len(flat), 2))]
        prim_b["WEIGHTS_0"] = b.accessor(np.round(wb * 255).astype(np.uint8), normalized=True)
    prims.append({"attributes": prim_b})
    b.doc["meshes"].append({"primitives": prims})
    root = b.node(name="Z_UP", matrix=MROOT.T.reshape(-1).tolist(), children=[1, 2])
    b.node(name="mesh", mesh=0, **({"skin": 0} if skin else {}), translation=[5.0, 5.0, 5.0])  # ignored
    b.node(name="armature", translation=list(ARM_T), rotation=list(ARM_Q), children=[3])
    b.node(name="j0", translation=list(J0_T), rotation=list(J0_Q), children=[4])
    b.node(name="j1", translation=list(J1_T), rotation=list(J1_Q))
    b.doc["scenes"][0]["nodes"] = [root]
    if skin:
        w0, w1 = rest_worlds()
        ibm = np.stack([np.linalg.inv(w0) @ MROOT, np.linalg.inv(w1) @ MROOT])
        b.doc["skins"] = [{"joints": [3, 4], "inverseBindMatrices": b.accessor(
            ibm.transpose(0, 2, 1).reshape(2, 16).astype(np.float32))}]
        anims = []
        for name, (interp, times, degs) in ANIMS.items():
            q = Rotation.from_euler("x", np.asarray(degs)[:, None], degrees=True).as_quat()
            tr = np.c_[np.zeros(3), 0.1 * np.arange(3), np.zeros(3)]
            if interp == "CUBICSPLINE":
                a, bt = cubic_tangents(3)
                q = np.stack([a, q, bt], 1).reshape(-1, 4)
                tr = np.stack([0.5 * tr, tr, -0.5 * tr], 1).reshape(-1, 3)
            ti = b.accessor(times.astype(np.float32))
            anims.append({"name": name, "samplers": [
                {"input": ti, "output": b.accessor(q.astype(np.float32)), "interpolation": interp},
                {"input": ti, "output": b.accessor(tr.astype(np.float32)), "interpolation": interp}],
                "channels": [{"sampler": 0, "target": {"node": 4, "path": "rotation"}},
                             {"sampler": 1, "target": {"node": 3, "path": "translation"}}]})
        b.doc["animations"] = anims
    return b.write(path)


def rest_worlds() -> tuple[np.ndarray, np.ndarray]:
    w0 = MROOT @ trs(ARM_T, ARM_Q) @ trs(J0_T, J0_Q)
    return w0, w0 @ trs(J1_T, J1_Q)


def hermite(t, times, values, a, b):
    k = max(i for i in range(len(times) - 1) if times[i] <= t) if t < times[-1] else len(times) - 2
    td = times[k + 1] - times[k]
    s = min(max((t - times[k]) / td, 0.0), 1.0)
    return ((2 * s**3 - 3 * s**2 + 1) * values[k] + (s**3 - 2 * s**2 + s) * td * b[k]
            + (-2 * s**3 + 3 * s**2) * values[k + 1] + (s**3 - s**2) * td * a[k + 1])


def reference_positions(name: str, t: float) -> np.ndarray:
    """Skinned positions at time t straight from the glTF definitions (y-up), then converted to z-up."""
    interp, times, degs = ANIMS[name]
    keys_q = Rotation.from_euler("x", np.asarray(degs)[:, None], degrees=True).as_quat()
    keys_t = np.c_[np.zeros(3), 0.1 * np.arange(3), np.zeros(3)]
    tc = min(max(t, times[0]), times[-1])
    if interp == "LINEAR":
        q = Slerp(times, Rotation.from_quat(keys_q))([tc]).as_quat()[0]
        tr = np.array([np.interp(tc, times, keys_t[:, c]) for c in range(3)])
    elif interp == "STEP":
        k = np.searchsorted(times, tc, side="right") - 1
        q, tr = keys_q[k], keys_t[k]
    else:
        a, b = cubic_tangents(3)
        q = hermite(tc, times, keys_q, a, b)
        q = q / np.linalg.norm(q)
        tr = hermite(tc, times, keys_t, 0.5 * keys_t, -0.5 * keys_t)
    w0 = MROOT @ trs(ARM_T, ARM_Q) @ trs(tr, J0_Q)
    w1 = w0 @ trs(J1_T, q)
    r0, r1 = rest_worlds()
    ibm0, ibm1 = np.linalg.inv(r0) @ MROOT, np.linalg.inv(r1) @ MROOT
    pos, weights, _ = prism_mesh()
    ph = np.c_[pos, np.ones(len(pos))]
    out = weights[:, :1] * (ph @ (w0 @ ibm0).T) + weights[:, 1:] * (ph @ (w1 @ ibm1).T)
    return (out @ C.T)[:, :3]


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_synthetic_rig_structure(tmp_path: Path, suffix: str) -> None:
    c = load_gltf(write_rig(tmp_path / f"rig{suffix}"))
    pos, _, faces = prism_mesh()
    assert c.joint_names == ["j0", "j1"] and list(c.parents) == [-1, 0]
    assert c.num_vertices == 9  # the duplicated middle ring and the non-indexed primitive are welded
    m = trimesh.Trimesh(c.rest_vertices, c.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    # the Z_UP root node and the y-up -> z-up conversion cancel: the prism stands along +z
    d, _ = cKDTree(c.rest_vertices).query(pos + [0.5, 0, 0])
    assert d.max() < 1e-6
    # normals were computed (none in the file): unit, pointing away from the prism axis on the sides
    assert np.allclose(np.linalg.norm(c.rest_normals, axis=1), 1, atol=1e-5)
    radial = c.rest_vertices[:, :2] - [0.5, 0]
    assert np.all((c.rest_normals[:, :2] * radial).sum(1) > 0)
    assert set(c.clips) == set(ANIMS)


@pytest.mark.parametrize("name", list(ANIMS))
def test_synthetic_samplers_match_reference(tmp_path: Path, name: str) -> None:
    c = load_gltf(write_rig(tmp_path / "rig.glb"), fps=10.0)
    poses = c.pose(name)
    times = ANIMS[name][1]
    assert poses.num_frames == int(round(times[-1] * 10)) + 1
    pos, _ = c.skin_mesh(poses)
    rest = prism_mesh()[0] + [0.5, 0, 0]
    order = cKDTree(c.rest_vertices).query(rest)[1]  # welded vertex of each reference vertex
    for f in range(poses.num_frames):
        ref = reference_positions(name, f / 10.0)
        np.testing.assert_allclose(pos[f][order], ref, atol=2e-5, err_msg=f"{name} frame {f}")


def test_bind_pose_reproduces_rest_mesh(tmp_path: Path) -> None:
    c = load_gltf(write_rig(tmp_path / "rig.glb"))
    pos, nrm = c.skin_mesh(c.pose(c.bind_clip()))
    np.testing.assert_allclose(pos[0], c.rest_vertices, atol=1e-5)
    np.testing.assert_allclose(nrm[0], c.rest_normals, atol=1e-5)


def test_weights_near_one_are_normalised(tmp_path: Path) -> None:
    c = load_gltf(write_rig(tmp_path / "rig.glb", weight_scale=1.01))
    np.testing.assert_allclose(c.weights.sum(1), 1.0, atol=1e-6)


def test_weights_far_from_one_are_normalised_with_a_warning(tmp_path: Path) -> None:
    """Exporters that do not normalise: weights summing to 0.7 load as the same rig (the posed vertices of the
    normalised rig, 1e-5: float32 positions) with one warning line naming the count."""
    ref = load_gltf(write_rig(tmp_path / "rig.glb"), fps=10.0)
    with pytest.warns(PrtWarning, match=r"^bad\.glb: skin weights of \d+ vertices do not sum to 1 .*; normalised$"):
        c = load_gltf(write_rig(tmp_path / "bad.glb", weight_scale=0.7), fps=10.0)
    np.testing.assert_allclose(c.weights.sum(1), 1.0, atol=1e-6)
    name = sorted(ref.clips)[0]
    np.testing.assert_allclose(c.skin_mesh(c.pose(name))[0], ref.skin_mesh(ref.pose(name))[0], atol=1e-5)


@pytest.mark.parametrize("kwargs, match", [
    ({"skin": False}, "no skinned mesh"),
    ({"nan": True}, "NaN"),
    ({"weight_scale": 0.0}, "all zero"),
])
def test_bad_gltf_raises(tmp_path: Path, kwargs: dict, match: str) -> None:
    path = write_rig(tmp_path / "bad.glb", **kwargs)
    with pytest.raises(PrtError, match=match) as e:
        load_gltf(path)
    assert "\n" not in str(e.value)


def test_stray_vertex_is_refused(tmp_path: Path) -> None:
    """One vertex far from the rest (the prism is 2 units tall) would become the character's size: with
    ``height`` every other vertex would collapse to a point. Refused at load time, with or without ``height``:
    a coordinate beyond the absolute bound, or a vertex beyond 100 median distances from the median (reference
    numbers from the mesh-space prism: the root transforms permute axes, so medians and distances carry over)."""
    for height in (None, 1.8):
        with pytest.raises(PrtError, match=r"^huge\.glb: vertex 4 at \(1e\+30, [^)]*\) has a coordinate beyond "
                                           r"1e\+07 \(limits\.MAX_COORDINATE\)$"):
            load_gltf(write_rig(tmp_path / "huge.glb", stray=1e30), height=height)
    ref = prism_mesh()[0].copy()
    ref[4, 0] = -3e3
    d = np.linalg.norm(ref - np.median(ref, axis=0), axis=1)
    typical = float(np.median(d))
    want = re.escape(f" lies {d[4] / typical:.0f} times the median vertex distance ({typical:.3g}) from the mesh's "
                     f"median, over 100 (limits.MAX_VERTEX_SPREAD): a stray vertex")
    for height in (None, 1.8):
        with pytest.raises(PrtError, match=r"^stray\.glb: vertex 4 at \(-2999(\.\d+)?, [^)]*\)" + want + "$"):
            load_gltf(write_rig(tmp_path / "stray.glb", stray=-3e3), height=height)


def test_far_but_plausible_vertex_loads(tmp_path: Path) -> None:
    """A vertex 5 units out (a few times the prism's size: a prop, a spike) is a shape, not a stray vertex."""
    c = load_gltf(write_rig(tmp_path / "far.glb", stray=5.0), height=1.8)
    assert np.ptp(c.rest_vertices[:, 2]) == pytest.approx(1.8, rel=1e-5)
    ref = prism_mesh()[0].copy()
    ref[4, 0] = 5.0
    d = np.linalg.norm(ref - ref.mean(0), axis=1)
    got = np.linalg.norm(c.rest_vertices - c.rest_vertices.mean(0), axis=1)
    np.testing.assert_allclose(np.sort(got) / got.max(), np.sort(d) / d.max(), atol=1e-5)  # the same shape


def test_bad_files_raise(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="not found"):
        load_gltf(tmp_path / "missing.glb")
    (tmp_path / "x.obj").write_text("v 0 0 0\n")
    with pytest.raises(PrtError, match="unknown character file format"):
        load_gltf(tmp_path / "x.obj")
    (tmp_path / "junk.glb").write_bytes(b"not a glb at all" * 8)
    with pytest.raises(PrtError):
        load_gltf(tmp_path / "junk.glb")


def test_unknown_clip_name(tmp_path: Path) -> None:
    c = load_gltf(write_rig(tmp_path / "rig.glb"))
    with pytest.raises(PrtError, match="unknown clip 'dance'"):
        c.pose("dance")


def write_renamed_rig(path: Path, entries: list[tuple[str, str | None]]) -> Path:
    """The synthetic rig as ``.gltf`` with its animations replaced by ``entries``: ``(source, name)``, where
    ``source`` is one of ``ANIMS`` (copied) or ``"armature"`` (a channel on the non-joint node 2 only), and
    ``name`` None drops the ``name`` key."""
    doc = json.loads(write_rig(path.with_suffix(".gltf")).read_text())
    by_name = {a["name"]: a for a in doc["animations"]}
    anims = []
    for source, name in entries:
        a = json.loads(json.dumps(by_name["lin" if source == "armature" else source]))
        if source == "armature":
            a["channels"] = [{"sampler": 1, "target": {"node": 2, "path": "translation"}}]
        a.pop("name")
        if name is not None:
            a["name"] = name
        anims.append(a)
    doc["animations"] = anims
    out = path.with_suffix(".gltf")
    out.write_text(json.dumps(doc))
    return out


def test_clip_naming_rule(tmp_path: Path) -> None:
    entries = [("lin", None), ("step", "A"), ("cubic", "A"), ("lin", "A_2"), ("armature", "static"), ("lin", ""),
               ("step", "animation_0")]
    c = load_gltf(write_renamed_rig(tmp_path / "named", entries))
    # unnamed -> animation_<index in the file>; the later of equal names -> <name>_<k>, k >= 2 free; names that
    # occur once are kept; an animation that moves no joint is no clip (but keeps its index)
    assert list(c.clips) == ["animation_0", "A", "A_3", "A_2", "animation_5", "animation_0_2"]
    assert [c.clips[n].num_frames for n in c.clips] == [31, 25, 37, 31, 31, 25]  # 1 s, 0.8 s, 1.2 s at 30 fps
    assert all(c.clips[n].name == n for n in c.clips)
    assert clip_names([(0, "Walk"), (1, None), (2, "Walk"), (3, "Walk"), (4, "Walk_2")]) == \
        ["Walk", "animation_1", "Walk_3", "Walk_4", "Walk_2"]
    assert clip_names([]) == []


# -- shared assets ----------------------------------------------------------------------------------
def _raw_fox_frame0(path: Path) -> np.ndarray:
    """Fox skinned at the first key of 'Walk' straight from the JSON (no welding, no sampler code), z-up."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()

    def acc(i: int) -> np.ndarray:
        a = g.accessors[i]
        v = g.bufferViews[a.bufferView]
        dt = {5126: np.float32, 5121: np.uint8, 5123: np.uint16}[a.componentType]
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
        start = (v.byteOffset or 0) + (a.byteOffset or 0)
        assert v.byteStride in (None, 0, np.dtype(dt).itemsize * n)
        return np.frombuffer(blob, dt, a.count * n, start).reshape(a.count, n).astype(np.float64)

    tr = {i: n.translation or (0, 0, 0) for i, n in enumerate(g.nodes)}
    rot = {i: n.rotation or (0, 0, 0, 1) for i, n in enumerate(g.nodes)}
    anim = next(a for a in g.animations if a.name == "Walk")
    for ch in anim.channels:
        out = acc(anim.samplers[ch.sampler].output)[0]
        assert ch.target.path in ("rotation", "translation")
        (rot if ch.target.path == "rotation" else tr)[ch.target.node] = out
    local = {i: trs(tr[i], rot[i]) for i in range(len(g.nodes))}
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}

    def world(i: int) -> np.ndarray:
        return local[i] if i not in parent else world(parent[i]) @ local[i]

    skin = g.skins[0]
    ibm = acc(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    mats = np.stack([world(j) @ ibm[k] for k, j in enumerate(skin.joints)])
    prim = g.meshes[0].primitives[0]
    p, jt, wt = acc(prim.attributes.POSITION), acc(prim.attributes.JOINTS_0).astype(int), acc(prim.attributes.WEIGHTS_0)
    ph = np.c_[p, np.ones(len(p))]
    out = np.einsum("vk,vkij,vj->vi", wt, mats[jt], ph)
    return (out @ C.T)[:, :3]


def test_fox(shared_data: Path) -> None:
    path = shared_data / "characters" / "Fox.glb"
    c = load_gltf(path)
    assert c.num_joints == 24
    assert {"Survey", "Walk", "Run"} <= set(c.clips)
    # non-indexed in the file: welding gives a closed mesh; no normals in the file: computed, outward
    m = trimesh.Trimesh(c.rest_vertices, c.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    fn = m.face_normals
    assert np.mean((c.rest_normals[c.faces].mean(1) * fn).sum(1) > 0) > 0.98
    pos, _ = c.skin_mesh(c.pose(c.bind_clip()))
    np.testing.assert_allclose(pos[0], c.rest_vertices, atol=1e-3)  # units: ~80 tall
    walk = c.pose("Walk")
    pos, nrm = c.skin_mesh(walk)
    ref = _raw_fox_frame0(path)
    d1, _ = cKDTree(pos[0]).query(ref)
    d2, _ = cKDTree(ref).query(pos[0])
    assert max(d1.max(), d2.max()) < 1e-3
    lo, hi = pos.min(1), pos.max(1)
    assert np.ptp(hi - lo, axis=0).max() > 1.0  # the bounds change over the walk cycle
    assert np.all(np.isfinite(nrm)) and np.allclose(np.linalg.norm(nrm, axis=-1), 1, atol=1e-4)
    assert hi[:, 2].max() > 50 and abs(lo[:, 2].min()) < 10  # z-up: standing on the ground, ~80 tall


def test_rigged_figure_z_up_root(shared_data: Path) -> None:
    c = load_gltf(shared_data / "characters" / "RiggedFigure.glb")
    assert c.num_joints == 19 and len(c.clips) == 1
    ext = np.ptp(c.rest_vertices, axis=0)
    assert ext[2] > 1.3 and ext[2] > 2 * ext[1]  # upright along z (the Z_UP node and y-up -> z-up cancel)
    assert abs(c.rest_vertices[:, 2].min()) < 0.02
    pos, _ = c.skin_mesh(c.pose(next(iter(c.clips))))
    ext = np.ptp(pos, axis=1)
    assert np.all(ext[:, 2] > 1.2) and np.all(ext[:, 2] > ext[:, 1])
    head = c.joint_names.index(max(c.joint_names, key=lambda n: c.pose(c.bind_clip()).world[0,
                                                                  c.joint_names.index(n), 2, 3]))
    w = c.pose(next(iter(c.clips))).world
    assert np.all(w[:, head, 2, 3] > 1.0)


def test_height_option(shared_data: Path) -> None:
    fox = load_gltf(shared_data / "characters" / "Fox.glb", height=1.8)
    assert np.ptp(fox.rest_vertices[:, 2]) == pytest.approx(1.8, rel=1e-5)
    pos, _ = fox.skin_mesh(fox.pose("Walk"))
    assert np.ptp(pos[..., 2], axis=1).max() < 2.0 and np.abs(pos[..., 2].min()) < 0.1


def test_interleaved_sparse_and_file_normals(tmp_path: Path) -> None:
    """Strided (interleaved) buffer views, a sparse accessor and normals stored in the file."""
    import base64
    import json

    pos, weights, faces = prism_mesh()
    radial = np.c_[pos[:, :2], np.zeros(len(pos))]
    nrm = radial / np.linalg.norm(radial, axis=1, keepdims=True)
    inter = np.concatenate([pos, nrm], axis=1).astype(np.float32)  # (9, 6): stride 24 bytes
    base_w = np.tile(np.array([1, 0, 0, 0], np.float32), (9, 1))
    sparse_idx = np.arange(3, 9).astype(np.uint16)
    sparse_val = np.c_[weights[3:], np.zeros((6, 2))].astype(np.float32)
    joints = np.tile(np.array([0, 1, 0, 0], np.uint8), (9, 1))
    w0, w1 = rest_worlds()
    ibm = np.stack([np.linalg.inv(w0) @ MROOT, np.linalg.inv(w1) @ MROOT]).transpose(0, 2, 1).astype(np.float32)
    chunks = [inter.tobytes(), base_w.tobytes(), sparse_idx.tobytes() + b"\0\0" * (len(sparse_idx) % 2),
              sparse_val.tobytes(), joints.tobytes(), faces.astype(np.uint16).tobytes(), ibm.tobytes()]
    views, blob = [], b""
    for k, c in enumerate(chunks):
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(c), **({"byteStride": 24} if k == 0
                                                                                       else {})})
        blob += c + b"\0" * (-len(c) % 4)
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"matrix": MROOT.T.reshape(-1).tolist(), "children": [1, 2]}, {"mesh": 0, "skin": 0},
                  {"name": "arm", "translation": list(ARM_T), "rotation": list(ARM_Q), "children": [3]},
                  {"name": "j0", "rotation": list(J0_Q), "children": [4]}, {"name": "j1", "translation": list(J1_T)}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "WEIGHTS_0": 2, "JOINTS_0": 3},
                                    "indices": 4}]}],
        "skins": [{"joints": [3, 4], "inverseBindMatrices": 5}],
        "accessors": [
            {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 9, "type": "VEC3"},
            {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": 9, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5126, "count": 9, "type": "VEC4",
             "sparse": {"count": 6, "indices": {"bufferView": 2, "componentType": 5123},
                        "values": {"bufferView": 3}}},
            {"bufferView": 4, "componentType": 5121, "count": 9, "type": "VEC4"},
            {"bufferView": 5, "componentType": 5123, "count": faces.size, "type": "SCALAR"},
            {"bufferView": 6, "componentType": 5126, "count": 2, "type": "MAT4"}],
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
    }
    path = tmp_path / "inter.gltf"
    path.write_text(json.dumps(doc))
    c = load_gltf(path)
    order = cKDTree(c.rest_vertices).query(pos + [0.5, 0, 0])[1]
    assert np.abs(c.rest_vertices[order] - (pos + [0.5, 0, 0])).max() < 1e-6
    np.testing.assert_allclose(c.rest_normals[order], nrm, atol=1e-6)  # file normals kept (z-up == mesh frame)
    dense = c.dense_weights[order]
    np.testing.assert_allclose(dense, weights, atol=1e-6)
