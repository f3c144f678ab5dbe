"""Deformable mesh checks and interior edge tables vs an independent dictionary walk over the faces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from prt_torch.deform.mesh import check_deformable_mesh, edge_pairs, interior_edges
from prt_torch.errors import PrtError
from tests.deform.sheets import sheet


def _reference_edges(faces: np.ndarray) -> set[tuple[int, int, int, int]]:
    """Plain-Python edge table: directed edge -> opposite vertex, paired with its reverse."""
    opposite: dict[tuple[int, int], int] = {}
    for a, b, c in faces.tolist():
        for s, d, o in ((a, b, c), (b, c, a), (c, a, b)):
            opposite[(s, d)] = o
    return {(i, j, k, opposite[(j, i)]) for (i, j), k in opposite.items() if i < j and (j, i) in opposite}


@pytest.mark.parametrize("mesh", ["sheet", "sphere"])
def test_interior_edges_match_reference(mesh: str) -> None:
    if mesh == "sheet":
        v, f = sheet(7, 5)
    else:
        ico = trimesh.creation.icosphere(subdivisions=2)
        v, f = np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64)
    check_deformable_mesh(v, f, "mesh")
    e = interior_edges(f)
    assert e.dtype == np.int64 and e.shape[1] == 4
    assert {tuple(r) for r in e.tolist()} == _reference_edges(f)
    assert len({tuple(r) for r in e.tolist()}) == len(e)
    keys = e[:, 0] * 10**6 + e[:, 1]
    assert np.all(np.diff(keys) > 0)  # sorted by (i, j): deterministic
    if mesh == "sphere":  # closed: every edge interior, E = 3T / 2
        assert len(e) == 3 * len(f) // 2 == len(edge_pairs(f, len(v)))
    # (i, j, k) and (j, i, l) are faces of the mesh up to a cyclic rotation
    rot = {tuple(np.roll(t, s)) for t in f.tolist() for s in range(3)}
    assert all((i, j, k) in rot and (j, i, l) in rot for i, j, k, l in e.tolist())
    # the order does not depend on the face order
    perm = np.random.default_rng(0).permutation(len(f))
    np.testing.assert_array_equal(interior_edges(np.roll(f[perm], 1, axis=1)), e)


def _one_line(exc: pytest.ExceptionInfo[PrtError]) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("cloth:")
    return msg


def test_bad_meshes_raise_one_line_errors() -> None:
    v, f = sheet(4, 4)
    nan = v.copy()
    nan[5, 1] = np.nan
    with pytest.raises(PrtError, match="NaN") as exc:
        check_deformable_mesh(nan, f, "cloth")
    _one_line(exc)
    inf = v.copy()
    inf[2, 0] = np.inf
    with pytest.raises(PrtError, match="inf"):
        check_deformable_mesh(inf, f, "cloth")
    bad = f.copy()
    bad[3, 2] = len(v)
    with pytest.raises(PrtError, match="out of range") as exc:
        check_deformable_mesh(v, bad, "cloth")
    _one_line(exc)
    bad[3, 2] = -1
    with pytest.raises(PrtError, match="out of range"):
        check_deformable_mesh(v, bad, "cloth")
    rep = f.copy()
    rep[0, 1] = rep[0, 0]
    with pytest.raises(PrtError, match="degenerate") as exc:
        check_deformable_mesh(v, rep, "cloth")
    _one_line(exc)
    flat = v.copy()
    flat[[f[0, 0], f[0, 1], f[0, 2]]] = flat[f[0, 0]]  # zero area without a repeated index
    with pytest.raises(PrtError, match="degenerate"):
        check_deformable_mesh(flat, f, "cloth")
    # a third face on an interior edge (a fin): non-manifold
    e = interior_edges(f)[0]
    fin_v = np.vstack([v, [[0.3, 0.3, 1.0]]])
    fin = np.vstack([f, [[e[0], e[1], len(v)]]])
    with pytest.raises(PrtError, match="non-manifold") as exc:
        check_deformable_mesh(fin_v, fin, "cloth")
    _one_line(exc)
    with pytest.raises(PrtError, match="non-manifold"):
        interior_edges(fin)
    flip = f.copy()
    flip[4] = flip[4, ::-1]  # one face turned over
    with pytest.raises(PrtError, match="orientation") as exc:
        check_deformable_mesh(v, flip, "cloth")
    _one_line(exc)
    with pytest.raises(PrtError, match="orientation"):
        interior_edges(flip)
    with pytest.raises(PrtError, match=r"\(T, 3\)"):
        check_deformable_mesh(v, f[:, :2], "cloth")
    with pytest.raises(PrtError, match="integers"):
        check_deformable_mesh(v, f.astype(np.float64), "cloth")
