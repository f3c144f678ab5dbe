"""Capsule blockers (issue 27): the capsule cone kernel against Embree on a triangulated capsule, a degenerate
capsule against the sphere kernel, numba vs torch vs ONNX parity, finite gradients; the rest-mesh fit, rigid
posing, the file round trip and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.bake.embree import RayScene
from prt_torch.bake.peaks import exact_peak_visibility
from prt_torch.blockers.capsule_cones import capsule_peak_visibility
from prt_torch.blockers.capsules import CapsuleSet, fit_capsules, pose_capsules
from prt_torch.blockers.cones import capsule_visibility_soa, sphere_peak_visibility
from prt_torch.blockers.spheres import vertex_bones
from prt_torch.errors import PrtError
from tests.tolerance import assert_bitwise


def random_scene(seed: int, n_b: int = 2, n_v: int = 400, n_s: int = 6) -> tuple[np.ndarray, ...]:
    """Receivers, capsules and peaks (float64) with plenty of overlaps: some capsules degenerate (spheres), some
    receivers inside a capsule, one segment along a peak's direction."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(n_b, n_v, 3))
    nrm = rng.normal(size=(n_b, n_v, 3))
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    a = rng.normal(size=(n_b, n_s, 3)) * 0.8
    b = a + rng.normal(size=(n_b, n_s, 3)) * 0.6
    b[:, 0] = a[:, 0]  # spheres
    d = rng.normal(size=(3, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b[:, 1] = a[:, 1] + 0.7 * d[0]  # parallel to the first peak
    r = rng.uniform(0.1, 0.4, n_s)
    pos[:, :20] = a[:, 2:3] + 0.5 * (b[:, 2:3] - a[:, 2:3]) + 0.05 * rng.normal(size=(n_b, 20, 3))  # inside
    ar = np.radians([0.5, 5.0, 20.0])
    return pos, nrm, a, b, r, d, ar


def capsule_mesh(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A triangulated capsule around segment ``a-b`` (vertices on the surface) and its inscribed radius (the
    faces' least distance to the segment, at the face centroids and edge midpoints: the mesh lies between)."""
    import trimesh

    length = float(np.linalg.norm(b - a))
    m = trimesh.creation.capsule(height=length, radius=radius, count=[64, 64])
    z = (b - a) / length
    x = np.cross(z, [0.3, 0.5, 0.8])
    x /= np.linalg.norm(x)
    rot = np.stack([x, np.cross(z, x), z], 1)  # columns: the capsule's x, y, z axes in the world
    verts = m.vertices @ rot.T + (a + b) / 2
    tri = verts[m.faces]
    probes = np.concatenate([tri.mean(1), (tri + np.roll(tri, 1, axis=1)).reshape(-1, 3) / 2])
    t = np.clip((probes - a) @ (b - a) / length ** 2, 0, 1)
    inner = float(np.linalg.norm(probes - a - t[:, None] * (b - a), axis=1).min())
    return verts, np.asarray(m.faces), inner


def test_one_capsule_vs_embree_on_a_triangulated_capsule() -> None:
    rng = np.random.default_rng(5)
    a, b, radius = np.array([0.1, -0.2, 0.4]), np.array([0.5, 0.3, 0.9]), 0.15
    verts, faces, inner = capsule_mesh(a, b, radius)
    n = 400
    # lights of 0.3-1 degree aimed near the capsule's outline: rays passing 0.6-1.4 radii from a point of the
    # segment (extended a little beyond it: the round caps), receivers 0.4-2 away
    q = a + rng.uniform(-0.3, 1.3, n)[:, None] * (b - a)
    off = np.cross(b - a, rng.normal(size=(n, 3)))
    off /= np.linalg.norm(off, axis=1, keepdims=True)
    target = q + off * (radius * rng.uniform(0.6, 1.4, n))[:, None]
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u -= ((u @ (b - a))[:, None] * (b - a)) / float((b - a) @ (b - a)) * rng.uniform(0, 1, n)[:, None]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pos = target - u * rng.uniform(0.4, 2.0, n)[:, None]
    t = np.clip((pos - a) @ (b - a) / float((b - a) @ (b - a)), 0, 1)
    out = np.linalg.norm(pos - a - t[:, None] * (b - a), axis=1) > 1.1 * radius  # receivers outside the capsule
    pos, u = pos[out], u[out]
    n = len(pos)
    r = np.radians(rng.uniform(0.3, 1.0, n))
    side = 16
    scene = RayScene(verts, faces)
    got, lo, hi = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        dirs, radii = u[i:i + 1], r[i:i + 1]
        got[i] = exact_peak_visibility(pos[i:i + 1], dirs, dirs, radii, 0.0, scene=scene, side=side)[0, 0]
        lo[i] = capsule_peak_visibility(pos[i:i + 1], dirs, a[None], b[None], np.array([radius]), dirs, radii)[0, 0]
        hi[i] = capsule_peak_visibility(pos[i:i + 1], dirs, a[None], b[None], np.array([inner]), dirs, radii)[0, 0]
    # the capsule kernel stands in the sphere nearest the ray for the capsule: exact for a delta light, the
    # penumbra's shape only approximately (a small disc: a small error); the samples' binomial error on top
    tol = 5 * np.sqrt(np.clip((lo + hi) / 2 * (1 - (lo + hi) / 2), 0, 1) / side ** 2) + 1 / side ** 2 + 0.05
    assert np.all(got >= lo - tol) and np.all(got <= hi + tol)
    assert ((got < 0.05).sum() > 50) and ((got > 0.95).sum() > 50) and (((got > 0.1) & (got < 0.9)).sum() > 20)
    assert np.mean(np.abs(got - (lo + hi) / 2)) < 0.02


def test_a_degenerate_capsule_is_the_sphere() -> None:
    pos, nrm, a, _, r, d, ar = random_scene(1)
    got = capsule_peak_visibility(pos, nrm, a, a, r, d, ar)
    want = sphere_peak_visibility(pos, nrm, a, r, d, ar)
    assert (want < 1).mean() > 0.3
    np.testing.assert_allclose(got, want, atol=1e-12)  # float64: the same formula, a == b gives s = 0 exactly


def test_numba_torch_and_onnx_agree(tmp_path: Path) -> None:
    import onnxruntime as ort
    import torch

    pos, nrm, a, b, r, d, ar = random_scene(2)
    ref = capsule_peak_visibility(pos, nrm, a, b, r, d, ar)
    assert 0.2 < (ref < 0.999).mean() < 0.95
    soa = capsule_visibility_soa(pos.transpose(0, 2, 1), nrm.transpose(0, 2, 1), a, b, r, d, ar, threads=True)
    assert_bitwise(soa, ref, why="the same compiled kernel on threads and on one thread, per-vertex independent")
    t64 = capsule_peak_visibility(*(torch.from_numpy(x) for x in (pos, nrm, a, b, r, d, ar))).numpy()
    np.testing.assert_allclose(t64, ref, atol=1e-9)
    # compact blocks of 64 vertices (sorted along a line) and small capsules: the culling drops most of them, the
    # results stay the uncull'd torch path's
    order = np.argsort(pos[..., 0], axis=1)
    srt = np.take_along_axis(pos, order[..., None], 1) * np.array([4.0, 0.5, 0.5])
    nrt = np.take_along_axis(nrm, order[..., None], 1)
    small = (a * 2, a * 2 + (b - a) * 0.5, r * 0.3)
    got = capsule_peak_visibility(srt, nrt, *small, d, ar)
    want = capsule_peak_visibility(*(torch.from_numpy(x) for x in (srt, nrt, *small, d, ar))).numpy()
    assert 0.02 < (want < 0.999).mean() < 0.9
    np.testing.assert_allclose(got, want, atol=1e-9)
    f32 = [torch.from_numpy(x.astype(np.float32)) for x in (pos, nrm, a, b, r, d, ar)]
    t32 = capsule_peak_visibility(*f32).numpy()
    assert np.abs(t32 - ref).max() < 1e-3

    class Graph(torch.nn.Module):
        def forward(self, *x: torch.Tensor) -> torch.Tensor:
            return capsule_peak_visibility(*x)

    path = tmp_path / "capsules.onnx"
    names = ["positions", "normals", "a", "b", "radii", "directions", "angular_radii"]
    torch.onnx.export(Graph(), tuple(f32), str(path), input_names=names, output_names=["visibility"],
                      dynamic_axes={"positions": {0: "B", 1: "V"}, "normals": {0: "B", 1: "V"}, "a": {0: "B"},
                                    "b": {0: "B"}, "directions": {0: "P"}, "angular_radii": {0: "P"}},
                      opset_version=17, dynamo=False)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    pos2, nrm2, a2, b2, r2, d2, ar2 = random_scene(3, n_b=1, n_v=300)  # other shapes: the axes are dynamic
    feeds = dict(zip(names, (x.astype(np.float32) for x in (pos2, nrm2, a2, b2, r2, d2[:2], ar2[:2])), strict=True))
    got = sess.run(None, feeds)[0]
    want = capsule_peak_visibility(pos2, nrm2, a2, b2, r2, d2[:2], ar2[:2])
    assert got.shape == want.shape and np.abs(got - want).max() < 1e-3


def test_gradients_are_finite() -> None:
    import torch

    pos, nrm, a, b, r, d, ar = random_scene(4)
    ta = torch.tensor(a, requires_grad=True)
    tb = torch.tensor(b, requires_grad=True)
    tr = torch.tensor(r, requires_grad=True)
    vis = capsule_peak_visibility(torch.tensor(pos), torch.tensor(nrm), ta, tb, tr, torch.tensor(d),
                                  torch.tensor(ar))
    vis.sum().backward()
    for g in (ta.grad, tb.grad, tr.grad):
        assert g is not None and torch.isfinite(g).all() and (g != 0).any()
    # the analytic gradient of the radii against a central difference
    eps = 1e-6
    num = (capsule_peak_visibility(pos, nrm, a, b, r + eps * np.eye(len(r))[3], d, ar).sum()
           - capsule_peak_visibility(pos, nrm, a, b, r - eps * np.eye(len(r))[3], d, ar).sum()) / (2 * eps)
    assert abs(float(tr.grad[3]) - num) < 1e-3 * max(1.0, abs(num))


# -- the set: fit, pose, file ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def character():  # noqa: ANN201
    from prt_torch.rig.builtin import make_character

    return make_character(density=0.25)


def test_fit_follows_the_bones(character) -> None:  # noqa: ANN001
    caps = fit_capsules(character, radius_quantile=1.0, end_quantile=0.0)
    vb = vertex_bones(character.joints, character.weights)
    counts = np.bincount(vb, minlength=character.num_joints)
    assert sorted(caps.bone.tolist()) == np.flatnonzero(counts).tolist()
    verts = character.rest_vertices.astype(np.float64)
    for k in range(caps.num_capsules):
        pts = verts[vb == caps.bone[k]]
        w = (caps.b[k] - caps.a[k]).astype(np.float64)
        t = np.clip((pts - caps.a[k]) @ w / max(float(w @ w), 1e-30), 0, 1)
        dist = np.linalg.norm(pts - caps.a[k] - t[:, None] * w, axis=1)
        # q = 1, e = 0: every vertex within r of the axis and at most r beyond an end, so within sqrt(2) r
        assert dist.max() <= np.sqrt(2) * caps.radius[k] * (1 + 1e-4)
        for e in (caps.a[k], caps.b[k]):  # the segment inside the bone's vertices' box
            assert np.all(e >= pts.min(0) - 1e-5) and np.all(e <= pts.max(0) + 1e-5)
    thin = fit_capsules(character, radius_quantile=0.2)
    assert np.all(thin.radius <= caps.radius + 1e-6) and np.median(thin.radius) < np.median(caps.radius)
    more = fit_capsules(character, n_capsules=int((counts > 0).sum()) + 5)
    assert more.num_capsules == (counts > 0).sum() + 5
    assert np.bincount(more.bone).max() >= 2
    with pytest.raises(PrtError, match="capsule count"):
        fit_capsules(character, n_capsules=3)
    with pytest.raises(PrtError, match="radius_quantile"):
        fit_capsules(character, radius_quantile=1.5)


def test_capsules_move_rigidly_and_round_trip(character, tmp_path: Path) -> None:  # noqa: ANN001
    caps = fit_capsules(character)
    poses = character.pose(next(iter(character.clips)))
    a, b = pose_capsules(caps, poses.skin)
    assert a.shape == (poses.skin.shape[0], caps.num_capsules, 3)
    # rigid: the segment's length is kept in every pose
    np.testing.assert_allclose(np.linalg.norm(b - a, axis=-1),
                               np.broadcast_to(np.linalg.norm(caps.b - caps.a, axis=-1), a.shape[:2]), atol=1e-4)
    path = tmp_path / "c.npz"
    caps.save(path)
    back = CapsuleSet.load(path)
    for name in ("bone", "a", "b", "radius"):
        assert_bitwise(getattr(back, name), getattr(caps, name), why="a save/load round trip")
    with pytest.raises(PrtError, match="capsule radii"):
        CapsuleSet(caps.bone, caps.a, caps.b, -caps.radius)
    with pytest.raises(PrtError, match="out of range"):
        pose_capsules(caps, poses.skin[:, :2])


def test_bad_input_is_one_line() -> None:
    pos, nrm, a, b, r, d, ar = random_scene(6)
    with pytest.raises(PrtError, match="angular radii"):
        capsule_peak_visibility(pos, nrm, a, b, r, d, ar * 0)
    with pytest.raises(PrtError, match="capsule endpoints b"):
        capsule_peak_visibility(pos, nrm, a, b[:, :2], r, d, ar)
    with pytest.raises(PrtError, match="capsule radii"):
        capsule_peak_visibility(pos, nrm, a, b, -r, d, ar)


def test_the_row_of_spheres_stands_in_for_the_capsules(character) -> None:  # noqa: ANN001
    caps = fit_capsules(character)
    sph = caps.spheres()
    rng = np.random.default_rng(7)
    for k in range(caps.num_capsules):
        mine = sph.bone == caps.bone[k]
        cen, rad = sph.center[mine].astype(np.float64), sph.radius[mine].astype(np.float64)
        a, b, r = caps.a[k].astype(np.float64), caps.b[k].astype(np.float64), float(caps.radius[k])
        # inside the capsule: every sphere (centres on the segment, the capsule's radius)
        t = np.clip((cen - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-30), 0, 1)
        assert np.linalg.norm(cen - a - t[:, None] * (b - a), axis=1).max() < 1e-5 and np.allclose(rad, r)
        # and they cover it but for a thin shell: points 0.96 r from a random point of the segment
        u = rng.normal(size=(200, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        p = a + rng.uniform(0, 1, (200, 1)) * (b - a) + 0.96 * r * u
        assert (np.linalg.norm(p[:, None] - cen[None], axis=2) <= rad * (1 + 1e-6)).any(1).all()
