"""Grid mesh, normals and vertex frames against closed forms and trimesh."""

from __future__ import annotations

import numpy as np
import trimesh

from prt_torch.heightfield.surface import Terrain, Waves, grid_faces, grid_frames, grid_normals, grid_positions


def test_plane_normals_and_frames_closed_form() -> None:
    """z = a x + b y: n = (-a, -b, 1)/|.|, t = normalise(x - (x.n) n), b = n x t, rows (t, b, n)."""
    n, a, b = 12, 0.3, -0.7
    x = np.linspace(0, 2.0, n)
    h = a * x[None, :] + b * x[:, None]
    nrm = grid_normals(h, extent=2.0)
    ref = np.array([-a, -b, 1.0]) / np.linalg.norm([-a, -b, 1.0])
    np.testing.assert_allclose(nrm, np.broadcast_to(ref, nrm.shape), atol=1e-12)
    f = grid_frames(h, extent=2.0).astype(np.float64)
    t = np.array([1.0, 0, 0]) - ref[0] * ref
    t /= np.linalg.norm(t)
    np.testing.assert_allclose(f[:, 0], np.broadcast_to(t, (n * n, 3)), atol=1e-6)
    np.testing.assert_allclose(f[:, 1], np.broadcast_to(np.cross(ref, t), (n * n, 3)), atol=1e-6)
    np.testing.assert_allclose(f[:, 2], np.broadcast_to(ref, (n * n, 3)), atol=1e-6)


def test_mesh_is_an_upward_grid_and_normals_match_trimesh() -> None:
    """2 (N-1)^2 upward triangles covering the square; interior vertex normals within 1 deg of trimesh's
    area-weighted ones on a smooth surface."""
    c = np.linspace(0, 1, 48)
    h = 0.05 * np.sin(2 * np.pi * c)[None, :] * np.cos(1.4 * np.pi * c)[:, None]
    pos = grid_positions(h)
    faces = grid_faces(48)
    assert faces.shape == (2 * 47 * 47, 3)
    mesh = trimesh.Trimesh(pos, faces, process=False)
    assert (mesh.face_normals[:, 2] > 0).all()
    assert abs(mesh.area_faces.sum() - mesh.area) < 1e-9 and abs(mesh.bounds[1, 0] - 1.0) < 1e-6
    inner = np.zeros((48, 48), bool)
    inner[2:-2, 2:-2] = True
    cos = (grid_normals(h).reshape(-1, 3)[inner.ravel()] * mesh.vertex_normals[inner.ravel()]).sum(1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.0


def test_generators_animate() -> None:
    """Frames differ over time, are finite and smooth enough to be a receiver."""
    for gen in (Waves(32), Terrain(32)):
        a, b = gen(0.0), gen(0.5)
        assert a.shape == (32, 32) and np.isfinite(a).all() and np.abs(a - b).max() > 1e-3
