"""Vertex frames without bones: orthonormal, exact under rigid motion, the polar rotation of the deformation
gradient (scipy.linalg.polar of the analytic Jacobian), coherent on a bent sheet, fast path == reference."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from prt_torch.deform.clusters import spatial_clusters
from prt_torch.deform.frames import FrameOperator, frame_coherence, frame_turn
from prt_torch.errors import PrtError
from prt_torch.rig.mesh import vertex_normals, vertex_normals_soa
from tests.deform.sheets import sheet
from tests.tolerance import assert_bitwise


def _soa(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(x, np.float32).transpose(0, 2, 1))


def _unsoa(frames: np.ndarray) -> np.ndarray:
    return frames.reshape(frames.shape[0], 3, 3, -1).transpose(0, 3, 1, 2)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def _assert_orthonormal_right_handed(fr: np.ndarray) -> None:
    f = fr.astype(np.float64)
    np.testing.assert_allclose(f @ np.swapaxes(f, -1, -2), np.broadcast_to(np.eye(3), f.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(f), 1.0, atol=1e-5)


@pytest.fixture(scope="module")
def wavy() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v, f = sheet(16, 12, width=1.5)
    v[:, 2] = 0.15 * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])
    return v, f, spatial_clusters(v, 5, seed=0)


def test_rest_frames_and_rigid_motion_exact(wavy) -> None:
    v, f, lab = wavy
    op = FrameOperator.from_rest(v, f, lab)
    rest = op.frames(v)
    assert rest.shape == (1, len(v), 3, 3) and rest.dtype == np.float32
    np.testing.assert_allclose(rest[0], op.rest_frames, atol=1e-6)
    _assert_orthonormal_right_handed(rest)
    np.testing.assert_allclose(rest[0, :, 2], vertex_normals(v, f), atol=1e-6)
    rots = Rotation.random(3, random_state=7).as_matrix()
    moved = np.einsum("bij,vj->bvi", rots, v) + np.array([[[4.0, -2.0, 1.0]], [[0.0, 0.0, 0.0]], [[-1.0, 3.0, 0.5]]])
    fr = op.frames(moved)
    _assert_orthonormal_right_handed(fr)
    want = np.einsum("bij,vrj->bvri", rots, op.rest_frames.astype(np.float64))  # every row rotated by R
    np.testing.assert_allclose(fr, want, atol=1e-5)
    assert frame_coherence(fr, f, lab, rest=op.rest_frames) < 1e-3  # rigid: every pair keeps its rest angle
    assert frame_coherence(fr, f, lab) == pytest.approx(frame_coherence(op.rest_frames, f, lab), abs=1e-3)
    fast, nrm = op.frames_soa(_soa(moved))
    assert fast.shape == (3, 9, len(v)) and nrm.shape == (3, 3, len(v)) and fast.dtype == np.float32
    np.testing.assert_allclose(_unsoa(fast), want, atol=2e-4)  # float32 positions up to 4 m from the origin
    assert_bitwise(fast[:, 6:9], nrm, why="the frames' normal rows are the normals, copied")


def test_affine_stretch_gives_the_polar_rotation_exactly() -> None:
    """Under an affine in-plane stretch + shear + rotation every one-ring is exact: t = polar rotation of the
    deformation gradient applied to the rest tangent (scipy.linalg.polar), not the stretched tangent."""
    v, f = sheet(9, 7, width=1.2)
    op = FrameOperator.from_rest(v, f, spatial_clusters(v, 3, seed=1))
    g = np.array([[1.3, 0.4, 0.0], [0.1, 0.7, 0.0], [0.0, 0.0, 1.0]])
    q = Rotation.from_euler("xyz", [0.4, -0.9, 2.2]).as_matrix()
    fr = op.frames(v @ (q @ g).T + 0.3)[0].astype(np.float64)
    r, _ = polar(q @ g)
    t0 = op.rest_frames[:, 0].astype(np.float64)
    np.testing.assert_allclose(fr[:, 0], t0 @ r.T, atol=1e-5)
    assert _angle_deg(t0 @ (q @ g).T, t0 @ r.T).max() > 5.0  # the stretched tangent would be far off


def test_mildly_stretched_bent_sheet_agrees_with_polar_reference() -> None:
    v, f = sheet(25, 13, width=2.0)
    op = FrameOperator.from_rest(v, f, spatial_clusters(v, 4, seed=2))
    x, y = v[:, 0], v[:, 1]
    pos = np.stack([1.06 * x + 0.04 * y**2, 0.95 * y + 0.03 * x * y, 0.15 * np.sin(1.5 * x)], axis=1)
    jx = np.stack([np.full_like(x, 1.06), 0.03 * y, 0.225 * np.cos(1.5 * x)], axis=1)  # analytic d pos / dx
    jy = np.stack([0.08 * y, 0.95 + 0.03 * x, np.zeros_like(x)], axis=1)
    nrm = np.cross(jx, jy)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    jac = np.stack([jx, jy, nrm], axis=2)  # (V, 3, 3): rest axes x, y, z -> posed
    rot = np.stack([polar(j)[0] for j in jac])
    q = Rotation.from_euler("zyx", [0.7, 0.2, -0.3]).as_matrix()
    fr = op.frames(pos @ q.T)[0].astype(np.float64)
    want = np.einsum("ij,vjk,vk->vi", q, rot, op.rest_frames[:, 0].astype(np.float64))
    err = _angle_deg(fr[:, 0], want)
    assert err.max() < 2.0, err.max()
    _assert_orthonormal_right_handed(fr[None])


def test_tangents_follow_a_cylinder_bend_coherently() -> None:
    """A 2 x 1 sheet (one cluster: PCA axis x) rolled isometrically about the y axis toward its normals, up to a
    quarter turn: t = d pos / dx (the exact rotation of the surface), coherent in space and time."""
    v, f = sheet(21, 11, width=2.0)
    lab = np.zeros(len(v), np.int32)
    op = FrameOperator.from_rest(v, f, lab)
    np.testing.assert_allclose(np.abs(op.rest_frames[:, 0]), np.tile([1.0, 0.0, 0.0], (len(v), 1)), atol=1e-6)
    sign = op.rest_frames[0, 0, 0]
    bends = np.linspace(0.05, np.pi / 2, 8)  # total bend angle of the sheet
    seq = []
    for total in bends:
        r = 2.0 / total
        a = v[:, 0] / r
        pos = np.stack([r * np.sin(a), v[:, 1], r * (1 - np.cos(a))], axis=1)
        fr = op.frames(pos)[0]
        tangent = sign * np.stack([np.cos(a), np.zeros_like(a), np.sin(a)], axis=1)
        normal = np.stack([-np.sin(a), np.zeros_like(a), np.cos(a)], axis=1)
        h_over_r = np.degrees(0.1 / r)
        # the tangent is off the exact one only by the smooth normal's discretisation (one-sided at the ends:
        # at most half an edge's bend), i.e. it stays in the plane of the bend
        n_err = _angle_deg(fr[:, 2], normal)
        assert n_err.max() <= 0.51 * h_over_r
        assert np.all(_angle_deg(fr[:, 0], tangent) <= n_err + 0.01)
        assert np.abs(fr[:, 0, 1]).max() < 1e-3
        assert frame_coherence(fr[None], f, lab) <= 1.05 * h_over_r + 1e-3
        assert frame_coherence(fr[None], f, lab) >= 0.95 * h_over_r
        assert frame_coherence(fr[None], f, lab, rest=op.rest_frames) <= 1.05 * h_over_r + 1e-3
        seq.append(fr)
    step = np.degrees(bends[1] - bends[0])  # the end of the sheet turns by exactly this much per step
    assert frame_turn(np.stack(seq)) <= step + 0.1


def test_fast_path_matches_reference_including_degenerate(wavy) -> None:
    v, f, lab = wavy
    v = np.vstack([v, [[9.0, 9.0, 9.0]]])  # an isolated vertex: no one-ring, normal (0, 0, 1)
    lab = np.append(lab, 0).astype(np.int32)
    op = FrameOperator.from_rest(v, f, lab)
    rng = np.random.default_rng(3)
    pos = v[None] + rng.normal(scale=0.01, size=(3, *v.shape))
    i = f[40, 0]
    nb = np.unique(f[np.any(f == i, axis=1)])
    pos[1, nb] = pos[1, i]  # a collapsed one-ring: no carried direction at all
    ref = op.frames(pos)
    fast, nrm = op.frames_soa(_soa(pos))
    assert np.isfinite(ref).all() and np.isfinite(fast).all()
    _assert_orthonormal_right_handed(ref)
    _assert_orthonormal_right_handed(_unsoa(fast))
    np.testing.assert_allclose(_unsoa(fast), ref, atol=1e-4)
    np.testing.assert_allclose(nrm.transpose(0, 2, 1), np.stack([vertex_normals(p, f) for p in pos]), atol=1e-5)
    np.testing.assert_allclose(vertex_normals_soa(_soa(pos), f), nrm, atol=0)
    np.testing.assert_allclose(ref[:, -1, 2], np.tile([0.0, 0.0, 1.0], (3, 1)))


def test_arrays_round_trip_through_npz(wavy, tmp_path) -> None:
    v, f, lab = wavy
    op = FrameOperator.from_rest(v, f, lab)
    np.savez(tmp_path / "op.npz", **op.arrays())
    with np.load(tmp_path / "op.npz") as d:
        back = FrameOperator.from_arrays(d)
    pos = v + 0.01 * np.sin(7 * v[:, [1, 2, 0]])
    assert_bitwise(back.frames(pos), op.frames(pos), why='the same operations on the round-tripped operator')
    assert_bitwise(back.frames_soa(_soa(pos[None]))[0], op.frames_soa(_soa(pos[None]))[0],
                   why='the same operations on the round-tripped operator')
    with pytest.raises(PrtError, match="lack"):
        FrameOperator.from_arrays({k: a for k, a in op.arrays().items() if k != "deform_faces"})


def test_bad_inputs(wavy) -> None:
    v, f, lab = wavy
    op = FrameOperator.from_rest(v, f, lab)
    bad = v.copy()
    bad[3, 0] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        op.frames(bad)
    with pytest.raises(PrtError, match="positions"):
        op.frames(v[:-1])
    with pytest.raises(PrtError, match="positions"):
        op.frames_soa(_soa(v[None, :-1]))
    with pytest.raises(PrtError, match="labels"):
        FrameOperator.from_rest(v, f, lab[:-1])
    with pytest.raises(PrtError, match="out of range"):
        FrameOperator.from_rest(v, f + 1, lab)
    with pytest.raises(PrtError, match="NaN"):
        FrameOperator.from_rest(bad, f, lab)


def test_torch_free_modules() -> None:
    code = ("import sys; import prt_torch.deform.frames, prt_torch.deform.mesh, prt_torch.deform.dihedral, "
            "prt_torch.deform.clusters; assert 'torch' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_long_sequences_equal_frame_by_frame(wavy) -> None:
    from prt_torch.deform.frames import CHUNK

    v, f, lab = wavy
    op = FrameOperator.from_rest(v, f, lab)
    pos = v[None] + 0.02 * np.random.default_rng(8).normal(size=(CHUNK + 3, *v.shape))
    assert_bitwise(op.frames(pos)[[0, CHUNK - 1, CHUNK, CHUNK + 2]],
                   np.concatenate([op.frames(pos[i]) for i in (0, CHUNK - 1, CHUNK, CHUNK + 2)]),
                   why="per-element arithmetic (CSR rows in nonzero order, elementwise ops): chunks split frames only")
