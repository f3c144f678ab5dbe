"""Voxelisation and the pyramid against independent references: trimesh's watertightness and point-in-sphere
tests, numpy block means, grid_sample at voxel centres."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.vct import build_pyramid, fit_grid, is_closed_mesh, voxelize


def _sphere(radius: float = 0.7, subdiv: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    import trimesh

    s = trimesh.creation.icosphere(subdiv, radius)
    return torch.tensor(s.vertices, dtype=torch.float32), torch.tensor(s.faces)


def test_closed_mesh_matches_trimesh() -> None:
    import trimesh

    box = trimesh.creation.box()
    assert is_closed_mesh(box.faces) == box.is_watertight is True
    open_box = box.faces[:-1]
    assert is_closed_mesh(open_box) is False


def test_solid_sphere_voxels_match_point_in_sphere() -> None:
    """Parity fill of an icosphere = voxel centres inside it (numpy distance test on the inscribed polyhedron's
    circumsphere), except a shell one voxel thick where the polyhedron and the sphere differ."""
    v, f = _sphere()
    grid = fit_grid(v, 64)
    solid = voxelize(v, f, grid, solid=True).numpy() > 0
    idx = np.stack(np.meshgrid(*[np.arange(64)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres = grid.origin.numpy() + (idx + 0.5) * grid.voxel
    r = np.linalg.norm(centres, axis=1).reshape(64, 64, 64)
    inner = r < 0.7 - 1.5 * grid.voxel
    outer = r > 0.7 + 1.5 * grid.voxel
    assert solid[inner].all()          # the interior is filled (no parity streaks)
    assert not solid[outer].any()      # nothing outside
    vol = solid.sum() * grid.voxel ** 3
    assert vol == pytest.approx(4 / 3 * np.pi * 0.7 ** 3, rel=0.15)


def test_surface_voxels_are_conservative_for_points_on_triangles() -> None:
    """Random points on every triangle fall in occupied voxels (the sampler marks every voxel it crosses)."""
    v, f = _sphere(0.7, 3)
    grid = fit_grid(v, 96)
    occ = voxelize(v, f, grid, solid=False).numpy()
    rng = np.random.default_rng(0)
    tri = v.numpy()[f.numpy()]  # (T, 3, 3)
    w = rng.dirichlet(np.ones(3), size=(len(tri), 20))  # (T, 20, 3)
    pts = np.einsum("tsk,tkc->tsc", w, tri).reshape(-1, 3)
    ijk = np.floor((pts - grid.origin.numpy()) / grid.voxel).astype(int)
    hit = occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] > 0
    assert hit.mean() > 0.999
    assert occ[occ.shape[0] // 2, occ.shape[1] // 2, occ.shape[2] // 2] == 0  # a hollow shell


def test_pyramid_levels_are_block_means_and_sampling_matches() -> None:
    rng = np.random.default_rng(1)
    occ = (rng.random((32, 32, 32)) > 0.7).astype(np.float32)
    pyr = build_pyramid(torch.tensor(occ))
    assert pyr.sizes == [32, 16, 8, 4, 2]
    for level, n in enumerate(pyr.sizes):
        b = 2 ** level
        ref = occ.reshape(n, b, n, b, n, b).mean(axis=(1, 3, 5))
        got = pyr.atlas[pyr.offsets[level]:pyr.offsets[level] + n, :n, :n].numpy()
        np.testing.assert_allclose(got, ref, atol=1e-6)
        # trilinear sampling at level-`level` voxel centres returns the block means exactly
        c = rng.integers(0, n, size=(50, 3))
        u = torch.tensor((c + 0.5) * b, dtype=torch.float32)
        val = pyr.sample(u, torch.full((50,), float(level))).numpy()
        np.testing.assert_allclose(val, ref[c[:, 0], c[:, 1], c[:, 2]], atol=1e-5)
    # outside the grid is empty, whatever the level
    assert float(pyr.sample(torch.tensor([[-40.0, 5.0, 5.0]]), torch.tensor([1.0]))) == 0.0


def test_bad_input_is_one_line_errors() -> None:
    v, f = _sphere()
    with pytest.raises(PrtError, match="voxel grid too small"):
        fit_grid(v, 16)  # a 16^3 grid cannot hold the margins and a mesh
    with pytest.raises(PrtError, match="voxel grid too small"):
        fit_grid(v, 64, bounds=((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)))  # the mesh sticks out of the box
    with pytest.raises(PrtError, match="resolution"):
        fit_grid(v, 1024)
    bad = v.clone()
    bad[3, 1] = float("nan")
    with pytest.raises(PrtError, match="NaN") as e:
        voxelize(bad, f, fit_grid(v, 64))
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="NaN"):
        fit_grid(bad, 64)
    with pytest.raises(PrtError, match="faces"):
        voxelize(v, f + 10_000, fit_grid(v, 64))
