"""Whole-scene truth (Embree over ground + posed meshes) and the composition rule, against independent
references: the exact cap of a sphere seen from the floor (closed-form ZH with scipy's Legendre polynomials),
dense quadrature of the exact visibility indicator, and the whole-scene Embree truth itself."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from prt_torch.bake.embree import RayScene
from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.scene.compose import Composer, constant_one, halfspace_visibility
from prt_torch.scene.ground import make_ground
from prt_torch.scene.truth import SceneTracer
from tests.scene.refs import cap_sh, project_indicator


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _frames_from_normals(n: np.ndarray) -> np.ndarray:
    """Orthonormal rows (t, b, n) for unit normals (any tangent)."""
    a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t = np.cross(a, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.stack([t, np.cross(n, t), n], axis=1).astype(np.float32)


ORDER = 4


def test_ground_truth_under_a_sphere_is_the_exact_cap() -> None:
    """Ground vertices under a mesh sphere: the scene truth is 1 - (exact cap), convention "one"."""
    r, c = 0.3, np.array([0.1, -0.05, 0.6])
    ball = trimesh.creation.icosphere(subdivisions=4, radius=r)
    g = make_ground((0.0, 0.0), 1.6, 0.0, resolution=6)
    tracer = SceneTracer(ORDER, n_rays=2048, offset=1e-4)
    (vis,) = tracer.frame([(g.vertices, g.faces), (ball.vertices + c, ball.faces)],
                          [(g.vertices, g.frames()[...], "one")])
    d = c[None] - g.vertices.astype(np.float64)
    dist = np.linalg.norm(d, axis=1)
    want = constant_one(ORDER)[None] - cap_sh(d / dist[:, None], np.arcsin(r / dist), ORDER)
    blocked_truth, blocked_want = constant_one(ORDER) - vis, constant_one(ORDER) - want
    assert _rel(blocked_truth, blocked_want) < 0.06


def test_character_receivers_vs_direct_quadrature() -> None:
    """Receivers on a convex mesh above the floor: the scene truth (both conventions) vs the projection of the exact
    indicator (upper hemisphere of the vertex AND above the floor plane) by dense quadrature."""
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.25)
    verts = ball.vertices + [0.0, 0.0, 0.4]
    g = make_ground((0.0, 0.0), 40.0, 0.0, resolution=4)  # large: the plane is nearly infinite from the ball
    idx = np.array([0, 5, 17, 40, 77, 120, 150])  # a spread of normals, some facing down
    pts = verts[idx]
    n = ball.vertex_normals[idx]
    frames = _frames_from_normals(n)
    tracer = SceneTracer(ORDER, n_rays=4096, offset=1e-4)
    scene = RayScene(*_merged(g, verts, ball.faces))
    for bh in ("zero", "one"):
        truth = tracer.trace(scene, pts, frames, bh)

        def indicator(dirs: np.ndarray, bh: str = bh) -> np.ndarray:
            up = dirs @ n.T > 0  # (N, V) upper hemisphere of each receiver
            free = dirs[:, 2:3] > 0  # the (convex) ball never occludes its own upper hemisphere
            return (up & free).astype(float) if bh == "zero" else 1.0 - (up & ~free)

        want = project_indicator(indicator, ORDER, n=200_000).T  # (V, C) world frame
        from prt_torch.sh.rotation import sh_rotation

        want_local = np.einsum("vij,vj->vi", sh_rotation(frames.astype(np.float64), ORDER), want)
        assert _rel(truth, want_local) < 0.04, bh


def _merged(g, verts, faces):
    from prt_torch.scene.truth import merged_mesh

    return merged_mesh([(g.vertices, g.faces), (verts, faces)])


@pytest.mark.parametrize("below_horizon", ["zero", "one"])
def test_composition_with_ground_matches_whole_scene_truth(below_horizon: str) -> None:
    """A small built-in character standing on the floor: its self-visibility (Embree, alone) composed with the
    ground half-space matches the whole-scene Embree truth (within the order-4 product truncation), far better
    than the self-visibility alone."""
    from prt_torch.rig.builtin import make_character

    ch = make_character(density=0.05)
    pos, nrm = ch.skin_mesh(ch.pose("squat").skin[5])
    frames = _frames_from_normals(nrm.astype(np.float64))
    offset = 1e-3
    rays = RaySet.make(1024, ORDER, len(pos), 0, below_horizon)
    alone = trace_frame(pos, frames, ch.faces, rays, offset).visibility
    g = make_ground((0.0, 0.0), 30.0, float(pos[:, 2].min()) - 1e-3, resolution=4)
    tracer = SceneTracer(ORDER, n_rays=1024, offset=offset)
    (truth,) = tracer.frame([(g.vertices, g.faces), (pos, ch.faces)], [(pos, frames, below_horizon)])
    comp = Composer(ORDER, below_horizon).in_scene(alone, frames, ground=True)
    err_self, err_comp = _rel(alone, truth), _rel(comp, truth)
    # order-4 truncation of the product is the remaining error (~0.08 here): stated tolerance 0.12
    assert err_comp < 0.15 * err_self and err_comp < 0.12, (err_self, err_comp)


def test_halfspace_is_the_rotated_upper_half_space() -> None:
    """The ground half-space in a vertex frame = quadrature of [w . up > 0] rotated into that frame."""
    rng = np.random.default_rng(0)
    n = rng.normal(size=(5, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    frames = _frames_from_normals(n)
    got = halfspace_visibility(frames, ORDER)
    world = project_indicator(lambda d: (d[:, 2] > 0).astype(float), ORDER)
    from prt_torch.sh.rotation import sh_rotation

    want = sh_rotation(frames.astype(np.float64), ORDER) @ world
    np.testing.assert_allclose(got, want, atol=2e-3)
