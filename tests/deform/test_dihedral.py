"""Signed dihedral angles vs an independent per-edge computation, rigid invariance, a known fold, the sign."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from prt_torch.deform.dihedral import dihedral_angles
from prt_torch.deform.mesh import interior_edges
from prt_torch.errors import PrtError
from tests.deform.sheets import sheet
from tests.tolerance import assert_bitwise


def _sub(a: list[float], b: list[float]) -> list[float]:
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _cross(a: list[float], b: list[float]) -> list[float]:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dot(a: list[float], b: list[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _reference(x: np.ndarray, row: list[int]) -> float:
    """Angle between the two face normals (math.atan2 of |n1 x n2| and n1 . n2), positive when the far vertex
    ``l`` lies on the normal side of face ``(i, j, k)``: the pair folds toward its normals."""
    i, j, k, l = (x[r].tolist() for r in row)
    n1 = _cross(_sub(j, i), _sub(k, i))
    n2 = _cross(_sub(i, j), _sub(l, j))
    c = _cross(n1, n2)
    unsigned = math.atan2(math.sqrt(_dot(c, c)), _dot(n1, n2))
    return unsigned if _dot(_sub(l, i), n1) > 0 else -unsigned


def _wavy(seed: int, amp: float) -> tuple[np.ndarray, np.ndarray]:
    v, f = sheet(9, 8)
    rng = np.random.default_rng(seed)
    v = v + rng.normal(scale=[0.02, 0.02, amp], size=v.shape)
    return v, f


@pytest.mark.parametrize("amp", [0.01, 0.2])
def test_matches_independent_per_edge_reference(amp: float) -> None:
    v, f = _wavy(1, amp)
    e = interior_edges(f)
    got = dihedral_angles(v, e)
    assert got.shape == (len(e),) and got.dtype == np.float64
    ref = np.array([_reference(v, r) for r in e.tolist()])
    assert np.abs(ref).max() > (0.05 if amp < 0.1 else 1.5)  # the mesh really is bent
    np.testing.assert_allclose(got, ref, atol=1e-9)
    assert np.all((got > -np.pi) & (got <= np.pi))


def test_rigid_invariance_batches_and_dtype() -> None:
    v, f = _wavy(2, 0.1)
    e = interior_edges(f)
    ref = dihedral_angles(v, e)
    rots = Rotation.random(4, random_state=3).as_matrix()
    moved = np.einsum("bij,vj->bvi", rots, v) + np.random.default_rng(4).normal(scale=3.0, size=(4, 1, 3))
    got = dihedral_angles(moved.reshape(2, 2, *v.shape), e)
    assert got.shape == (2, 2, len(e))
    np.testing.assert_allclose(got.reshape(4, -1), np.broadcast_to(ref, (4, len(e))), atol=1e-9)
    np.testing.assert_allclose(dihedral_angles(2.5 * v, e), ref, atol=1e-9)  # scale invariant
    f32 = dihedral_angles(v.astype(np.float32), e)
    assert f32.dtype == np.float32
    np.testing.assert_allclose(f32, ref, atol=2e-5)


@pytest.mark.parametrize("alpha_deg", [30.0, -75.0, 150.0])
def test_sheet_folded_along_a_line_by_a_known_angle(alpha_deg: float) -> None:
    """The half x > 0.5 is turned about the line x = 0.5 toward +z (the normals' side) by alpha: the edges on the
    fold line show +alpha (folding toward the normals is positive), every other edge 0."""
    v, f = sheet(11, 6)
    a = math.radians(alpha_deg)
    x = v.copy()
    right = v[:, 0] > 0.5 + 1e-9
    d = v[right, 0] - 0.5
    x[right, 0] = 0.5 + d * math.cos(a)
    x[right, 2] = d * math.sin(a)
    e = interior_edges(f)
    got = dihedral_angles(x, e)
    on_fold = np.isclose(v[e[:, 0], 0], 0.5) & np.isclose(v[e[:, 1], 0], 0.5)
    assert on_fold.sum() == 5
    np.testing.assert_allclose(got[on_fold], a, atol=1e-12)
    np.testing.assert_allclose(got[~on_fold], 0.0, atol=1e-12)
    assert_bitwise(dihedral_angles(v, e), 0.0, why='a flat sheet: atan2(0, +) is exactly 0')


def test_convex_closed_mesh_is_negative_and_fully_folded_is_pi() -> None:
    ico = trimesh.creation.icosphere(subdivisions=1)  # outward normals: every edge a ridge
    e = interior_edges(np.asarray(ico.faces))
    got = dihedral_angles(np.asarray(ico.vertices), e)
    assert np.all(got < 0)
    # two triangles folded flat onto each other: +pi (the interval is (-pi, pi])
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 1, 0]])
    ang = dihedral_angles(x, np.array([[0, 1, 2, 3]]))
    assert ang[0] == np.float64(np.pi)


def test_bad_inputs() -> None:
    v, f = sheet(3, 3)
    e = interior_edges(f)
    with pytest.raises(PrtError, match="out of range"):
        dihedral_angles(v, e + len(v))
    with pytest.raises(PrtError, match=r"\(E, 4\)"):
        dihedral_angles(v, e[:, :3])
    with pytest.raises(PrtError, match=r"\(\.\.\., V, 3\)"):
        dihedral_angles(v[:, :2], e)
