"""The numpy dihedral angles (prt_torch.deform.dihedral_soa) vs a per-edge math.atan2 loop and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.deform.dihedral_soa import DihedralSoA
from prt_torch.deform.mesh import interior_edges
from prt_torch.errors import PrtError
from tests.deform.sheets import sheet
from tests.deform.test_dihedral import _reference


def _soa(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x.transpose(0, 2, 1))


def test_matches_the_numpy_rule_on_bent_sheets() -> None:
    """Random bends (several frames at once, float32) == the per-edge math.atan2 reference, to float32 rounding."""
    v, f = sheet(12, 10)
    e = interior_edges(f)
    rng = np.random.default_rng(5)
    x = (v[None] + rng.normal(scale=[0.02, 0.02, 0.15], size=(3, *v.shape))).astype(np.float32)
    got = DihedralSoA(e, v.shape[0])(_soa(x))
    ref = np.array([[_reference(xb.astype(np.float64), row) for row in e.tolist()] for xb in x])
    keep = np.abs(ref) < np.pi - 1e-3  # +-pi folds may land on either side in float32
    assert got.shape == ref.shape and got.dtype == np.float32 and keep.mean() > 0.99
    np.testing.assert_allclose(got[keep], ref[keep], atol=1e-5)


@pytest.mark.parametrize("fold", [0.0, 0.4, -1.1, 2.9])
def test_hinge_angle_closed_form(fold: float) -> None:
    """Two triangles about the x axis, the second turned by ``fold`` about the shared edge: |angle| == |fold|
    (and the sign flips with the fold), invariant under a rigid motion."""
    c, s = math.cos(fold), math.sin(fold)
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -c, -s]], np.float64)
    edges = np.array([[0, 1, 2, 3]])
    d = DihedralSoA(edges, 4)
    got = float(d(_soa(x[None].astype(np.float32)))[0, 0])
    assert abs(abs(got) - abs(fold)) < 1e-5
    # float64 in stays float64 (the bake's features)
    assert float(d(_soa(x[None]))[0, 0]) == pytest.approx(got, abs=1e-5)
    q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    moved = x @ q.T + np.array([3.0, -2.0, 1.0])
    assert float(d(_soa(moved[None].astype(np.float32)))[0, 0]) == pytest.approx(got, abs=1e-5)


def test_bad_input() -> None:
    v, f = sheet(4, 3)
    d = DihedralSoA(interior_edges(f), v.shape[0])
    with pytest.raises(PrtError, match=r"\(B, 3, 12\)"):
        d(np.zeros((1, 12, 3), np.float32))
    with pytest.raises(PrtError):
        DihedralSoA(np.array([[0, 1, 2, 99]]), 12)
