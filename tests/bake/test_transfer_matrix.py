"""Transfer matrices from the bake's rays vs independent references: hemisphere quadrature of the restricted SH
rotation, Lebedev quadrature of the full rotation, brute-force Embree ray quadrature under random lighting, and
the existing diffuse interreflection code."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("embreex")

from prt_torch.bake.embree import RayScene  # noqa: E402
from prt_torch.bake.trace import RaySet, trace_frame  # noqa: E402
from prt_torch.brdf.factor import hemisphere_rule  # noqa: E402
from prt_torch.errors import PrtError  # noqa: E402
from prt_torch.s001.bake import exit_term_rows, transfer_matrices  # noqa: E402
from prt_torch.sh.basis import sh_basis  # noqa: E402
from prt_torch.sh.quadrature import hemisphere_directions, random_rotations, sphere_quadrature  # noqa: E402

NO_FACES = np.zeros((0, 3), dtype=np.int64)


def _frames(n: int, seed: int) -> np.ndarray:
    """``(n, 3, 3)`` random right-handed frames (rows t, b, n)."""
    return random_rotations(n, seed=seed).astype(np.float64)


def _frames_from_normals(normals: np.ndarray) -> np.ndarray:
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(a, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.stack([t, np.cross(n, t), n], axis=1)


def _far_scene() -> RayScene:
    """A scene whose only triangle no hemisphere ray of a point near the origin can hit."""
    return RayScene(np.array([[100, 100, 100], [101, 100, 100], [100, 101, 100.0]], np.float32), np.array([[0, 1, 2]]))


def _points_matrices(points, frames, scene, n_rays, order, below="zero"):
    rays = RaySet.make(n_rays, 2, len(points), 0, below_horizon=below)
    res = trace_frame(points, frames, NO_FACES, rays, 1e-4, scene=scene, keep_hits=True)
    return transfer_matrices(frames, res.hits, rays, NO_FACES, order=order, bounces=0), rays, res


def test_unoccluded_zero_is_hemisphere_restricted_rotation():
    F = _frames(3, seed=1)
    T, _, _ = _points_matrices(np.zeros((3, 3)), F, _far_scene(), 4096, 4)
    u, w = hemisphere_rule(24, 48)  # exact for these polynomials on the upper hemisphere (local frame)
    for v in range(3):
        ref = (sh_basis(u, 4) * w[:, None]).T @ sh_basis(u @ F[v], 4)  # y_i(u) y_j(F^T u)
        np.testing.assert_allclose(T[v], ref, atol=1.5e-3)


def test_unoccluded_one_is_the_rotation_matrix():
    F = _frames(2, seed=2)
    T, _, _ = _points_matrices(np.zeros((2, 3)), F, _far_scene(), 512, 4, below="one")
    x, w = sphere_quadrature(12)
    for v in range(2):
        ref = (sh_basis(x, 4) * w[:, None]).T @ sh_basis(x @ F[v], 4)  # int y_i(F w) y_j(w) dw, w = F^T x
        np.testing.assert_allclose(T[v], ref, atol=2e-5)
        # and l_local = T L is the lighting in the frame: evaluating it at a local direction u gives L(F^T u)
        L = np.random.default_rng(v).normal(size=16)
        u = np.array([[0.3, -0.4, math.sqrt(0.75)]])
        assert sh_basis(u, 4) @ (T[v] @ L) == pytest.approx(sh_basis(u @ F[v], 4) @ L, abs=1e-4)


def _plane_scene(height: float = 0.5) -> RayScene:
    """A half-plane roof at z = height over x > 0 (two triangles)."""
    v = np.array([[0, -50, height], [50, -50, height], [50, 50, height], [0, 50, height]], np.float32)
    return RayScene(v, np.array([[0, 1, 2], [0, 2, 3]]))


@pytest.mark.parametrize("below", ["zero", "one"])
def test_shadowed_transfer_vs_brute_force_rays(below):
    """A vertex under a half-plane roof: T @ L vs the local SH of V(w) L(w) by 200k independent Embree rays."""
    F = _frames_from_normals(np.array([[0.3, 0.1, 1.0], [-0.5, 0.2, 0.8]]))
    pts = np.array([[0.2, 0.0, 0.0], [-0.1, 0.3, 0.0]])
    scene = _plane_scene()
    T, _, _ = _points_matrices(pts, F, scene, 8192, 4, below=below)
    L = np.random.default_rng(0).normal(size=16)
    n = 200_000
    u = hemisphere_directions(n, seed=7)  # local, upper hemisphere, equal weights 2 pi / n
    for v in range(2):
        wdir = u @ F[v]
        occ = scene.occluded(np.repeat(pts[v:v + 1] + 1e-4 * F[v, 2], n, 0).astype(np.float32),
                             wdir.astype(np.float32))
        vis = np.logical_not(occ).astype(np.float64)
        ref = (2 * math.pi / n) * (sh_basis(u, 4) * (vis * (sh_basis(wdir, 4) @ L))[:, None]).sum(0)
        if below == "one":  # the lower hemisphere is unoccluded
            ref += (2 * math.pi / n) * (sh_basis(-u, 4) * (sh_basis(-wdir, 4) @ L)[:, None]).sum(0)
        got = T[v] @ L
        assert occ.mean() > 0.2  # really shadowed
        assert np.linalg.norm(got - ref) <= 0.01 * np.linalg.norm(ref)


def _open_box(n: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit box without its top, normals inward: ``(V, 3)`` vertices, ``(T, 3)`` faces, ``(V, 3)`` normals."""
    import trimesh

    box = trimesh.creation.box(extents=(1, 1, 1))
    for _ in range(2):
        box = box.subdivide()
    keep = box.face_normals[:, 2] < 0.5  # drop the top
    box.update_faces(keep)
    box.remove_unreferenced_vertices()
    box.invert()  # normals inward
    return np.asarray(box.vertices), np.asarray(box.faces), np.asarray(box.vertex_normals)


@pytest.mark.parametrize("bounces", [1, 2])
def test_interreflection_matches_diffuse_bounce_code(bounces):
    """The (l=1, m=0) row of T (the cosine on the hemisphere) times sqrt(4 pi/3)/pi = the bake's transfer."""
    pos, faces, nrm = _open_box()
    F = _frames_from_normals(nrm)
    rays = RaySet.make(256, 2, len(pos), 0, below_horizon="zero")
    res = trace_frame(pos, F, faces, rays, 1e-4, transfer_order=3, bounces=bounces, albedo=0.7, keep_hits=True)
    T = transfer_matrices(F, res.hits, rays, faces, order=3, bounces=bounces, albedo=0.7)
    diffuse = T[:, 2, :] * math.sqrt(4 * math.pi / 3) / math.pi
    np.testing.assert_allclose(diffuse, res.transfer, atol=2e-5 * np.abs(res.transfer).max())
    T0 = transfer_matrices(F, res.hits, rays, faces, order=3, bounces=0)
    assert np.abs(T - T0).max() > 0.01  # the bounce is really there


def test_one_minus_zero_is_the_lower_hemisphere():
    pos, faces, nrm = _open_box()
    F = _frames_from_normals(nrm)[:5]
    scene = RayScene(pos, faces)
    Tz, _, _ = _points_matrices(pos[:5], F, scene, 1024, 3, "zero")
    To, _, _ = _points_matrices(pos[:5], F, scene, 1024, 3, "one")
    u, w = hemisphere_rule(24, 48)
    lo = -u
    for v in range(5):
        ref = (sh_basis(lo, 3) * w[:, None]).T @ sh_basis(lo @ F[v], 3)
        np.testing.assert_allclose(To[v] - Tz[v], ref, atol=4e-3)


def test_exit_term_is_reflected_once_by_white_lambert():
    from prt_torch.brdf.analytic import Lambert
    from prt_torch.s001.brdf_matrix import brdf_matrix

    k = exit_term_rows(4)
    B = brdf_matrix(Lambert(), 4)
    wo = hemisphere_directions(50, seed=1)
    np.testing.assert_allclose(sh_basis(wo, 4) @ B @ k, 1.0, atol=1e-6)


def test_bad_inputs_are_one_line_errors():
    F = _frames(2, seed=4)
    rays = RaySet.make(64, 2, 2, 0)
    res = trace_frame(np.zeros((2, 3)), F, NO_FACES, rays, 1e-4, scene=_far_scene(), keep_hits=True)
    cases = [
        lambda: transfer_matrices(F, None, rays, NO_FACES),
        lambda: transfer_matrices(F[:1], res.hits, rays, NO_FACES),
        lambda: transfer_matrices(F, res.hits, rays, NO_FACES, order=9),
        lambda: transfer_matrices(F, res.hits, rays, NO_FACES, bounces=3),
        lambda: transfer_matrices(F, res.hits, rays, NO_FACES, exit_transfer=np.zeros((2, 4))),
    ]
    for case in cases:
        with pytest.raises(PrtError) as e:
            case()
        assert "\n" not in str(e.value)


def test_bake_stores_matrices_and_subsurface_from_the_same_rays(tmp_path):
    """``prt bake`` path: the stored matrices' diffuse row equals the stored transfer (same rays, same bounce),
    ``subsurface`` is stored, and a resume with another matrix order is refused."""
    from prt_torch.bake.runner import bake
    from prt_torch.bake.store import open_dataset
    from prt_torch.config import config_from_dict

    cfg = {
        "name": "tm",
        "run_dir": str(tmp_path / "tm"),
        "character": {"source": "builtin", "density": 0.05, "fps": 3.0, "random_poses": 3, "heldout_clips": [],
                      "seed": 1},
        "bake": {"order": 3, "n_rays": 64, "frames_per_task": 2, "seed": 7, "below_horizon": "zero",
                 "transfer": True, "transfer_order": 3, "bounces": 1, "transfer_matrix": True, "matrix_order": 3,
                 "matrix_bounces": 1, "subsurface": {"scale": 1000.0}},
    }
    path = bake(config_from_dict(cfg), workers=1, progress=False)
    ds = open_dataset(path)
    T = np.asarray(ds.array("transfer_matrix")[:])
    t = np.asarray(ds.array("transfer")[:])
    s = np.asarray(ds.array("subsurface")[:])
    assert T.shape == (3, ds.n_vertices, 9, 9) and s.shape == t.shape
    reflected = T - exit_term_rows(3)[:, None] * s[..., None, :9]  # less the subsurface exit term k s^T
    np.testing.assert_allclose(reflected[..., 2, :] * math.sqrt(4 * math.pi / 3) / math.pi, t, atol=1e-5)
    assert np.isfinite(s).all() and (s[..., 0] > 0).mean() > 0.9
    cfg["bake"]["matrix_order"] = 2
    with pytest.raises(PrtError, match="matrix_order"):
        bake(config_from_dict(cfg), workers=1, progress=False)
