"""The package's own mesh helpers against trimesh: welding, area-weighted vertex normals, adjacency, mesh checks.

The package keeps its own code (``docs/DESIGN.md``, "Mesh helpers and trimesh": the same results, trimesh's
import alone costs about a second per process and its face adjacency is slower); these tests hold the two to the
same answers on the built-in humanoid and on trimesh's icosphere.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh import geometry, grouping, util

from prt_torch.deform.mesh import check_deformable_mesh, edge_pairs, interior_edges
from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rig.mesh import normal_scatter, vertex_normals, vertex_normals_soa, weld
from tests.tolerance import assert_bitwise, two_path_atol

F32 = float(np.finfo(np.float32).eps)


@pytest.fixture(scope="module", params=["humanoid", "icosphere"])
def mesh(request: pytest.FixtureRequest, humanoid: Character) -> tuple[np.ndarray, np.ndarray]:
    if request.param == "humanoid":
        return humanoid.rest_vertices.astype(np.float64), humanoid.faces
    ico = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64)


def test_weld_matches_trimesh_unique_rows(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    soup = v[f].reshape(-1, 3)  # every corner its own vertex
    sf = np.arange(soup.shape[0]).reshape(-1, 3)
    joints = (np.arange(v.shape[0]) % 5)[f].reshape(-1, 1).repeat(2, axis=1)  # a skin key: splits some positions
    weights = np.full(joints.shape, 0.5)
    pos, faces, (jw, ww), index = weld(soup, sf, joints, weights)
    table = np.concatenate([soup, joints.astype(np.float64), weights], axis=1)
    keep, inverse = grouping.unique_rows(table, digits=6, keep_order=True)
    assert_bitwise(pos, soup[keep], why="both keep the first occurrence of each row, copied")
    np.testing.assert_array_equal(index, inverse)
    np.testing.assert_array_equal(jw, joints[keep])
    # positions alone: trimesh's merge_vertices welds the soup back to the original vertex count
    merged = trimesh.Trimesh(soup, sf, process=False)
    merged.merge_vertices()
    p2, f2, _, _ = weld(soup, sf)
    assert len(p2) == len(merged.vertices) == len(v) and len(f2) == len(f)


def test_vertex_normals_match_trimesh_area_weighted(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    ours = vertex_normals(v, f).astype(np.float64)
    # trimesh's sparse sum of the unnormalised face normals (= area weights), unitised; ours rounds to float32
    ref = util.unitize(geometry.mean_vertex_normals(len(v), f, trimesh.triangles.cross(v[f])))
    np.testing.assert_allclose(ours, ref, rtol=0, atol=F32)  # half an ulp of a unit component, plus float64 noise
    # the float32 vertex-last path on the float32 positions: edges p1 - p0 rounded relative to |p|, a cross
    # product, a sparse sum and a normalisation, in float32; per vertex the terms (relative to the normal's length)
    # are bounded by sum_t (|p|_t (|e1| + |e2|) + |e1| |e2|) / |sum_t e1 x e2| (cancellation of the sum included)
    v32 = v.astype(np.float32)
    w = v32.astype(np.float64)
    ref = util.unitize(geometry.mean_vertex_normals(len(v), f, trimesh.triangles.cross(w[f])))
    e1 = np.linalg.norm(w[f[:, 1]] - w[f[:, 0]], axis=1)
    e2 = np.linalg.norm(w[f[:, 2]] - w[f[:, 0]], axis=1)
    pmax = np.abs(w[f]).max(axis=(1, 2)) * np.sqrt(3)
    bound = geometry.index_sparse(len(v), f).astype(np.float64) @ (pmax * (e1 + e2) + e1 * e2)
    summed = geometry.index_sparse(len(v), f).astype(np.float64) @ trimesh.triangles.cross(w[f])
    amp = bound / np.linalg.norm(summed, axis=1)
    soa = vertex_normals_soa(v32.T[None].copy(), f, normal_scatter(f, len(v)))[0].T
    assert (np.abs(soa - ref) <= np.array([two_path_atol(16, a) for a in amp])[:, None]).all()


def test_normal_scatter_is_trimesh_index_sparse(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    ours = normal_scatter(f, len(v)).tocoo()
    ref = geometry.index_sparse(len(v), f).tocoo()
    a = np.lexsort((ours.col, ours.row))
    b = np.lexsort((ref.col, ref.row))
    np.testing.assert_array_equal(np.c_[ours.row[a], ours.col[a]], np.c_[ref.row[b], ref.col[b]])


def test_adjacency_matches_trimesh(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    m = trimesh.Trimesh(v, f, process=False)
    eu = np.sort(m.edges_unique, axis=1)
    np.testing.assert_array_equal(edge_pairs(f, len(v)), eu[np.lexsort((eu[:, 1], eu[:, 0]))])
    rows = interior_edges(f)
    adj = np.sort(m.face_adjacency_edges, axis=1)
    order = np.lexsort((adj[:, 1], adj[:, 0]))
    np.testing.assert_array_equal(rows[:, :2], adj[order])
    np.testing.assert_array_equal(np.sort(rows[:, 2:], axis=1), np.sort(m.face_adjacency_unshared[order], axis=1))
    # orientation: (i, j, k) is a face up to a cyclic rotation (i -> j is its directed edge)
    cyc = {tuple(np.roll(t, s)) for t in f.tolist() for s in range(3)}
    assert all((i, j, k) in cyc and (j, i, l) in cyc for i, j, k, l in rows.tolist())


def test_mesh_check_agrees_with_trimesh_winding(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    assert trimesh.Trimesh(v, f, process=False).is_winding_consistent
    check_deformable_mesh(v, f, "mesh")
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert not trimesh.Trimesh(v, flipped, process=False).is_winding_consistent
    with pytest.raises(PrtError, match="inconsistent face orientation"):
        check_deformable_mesh(v, flipped, "mesh")
