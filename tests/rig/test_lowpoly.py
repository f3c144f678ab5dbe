"""Low-poly characters: midpoint subdivision carried by the skin (vs trimesh and closed forms) and the advice line.

References: trimesh's own subdivision of the POSED mesh and its edge table, the closed form of what linear blend
skinning adds to a midpoint, surface area (midpoints lie on the flat triangles), and linear UVs.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from prt_torch.cli import main
from prt_torch.config import RunConfig, load_config
from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rig.lowpoly import (
    LOW_POLY_VERTICES,
    MAX_SUBDIVIDE,
    low_poly_advice,
    subdivide_character,
    subdivide_mesh,
    suggested_levels,
)
from tests.tolerance import assert_bitwise

F32 = float(np.finfo(np.float32).eps)
SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "characters"


def _with_uv(c: Character) -> Character:
    """The character with UVs that are a linear function of the rest position (uv = (x, y) per corner)."""
    c2 = Character(c.name, c.joint_names, c.parents, c.bind_local, c.inverse_bind, c.rest_vertices, c.rest_normals,
                   c.faces, c.joints, c.weights, dict(c.clips), c.joint_limits, c.rest_vertices[c.faces][..., :2])
    return c2


@pytest.fixture(scope="module")
def sub1(humanoid: Character) -> tuple[Character, Character]:
    c = _with_uv(humanoid)
    return c, subdivide_character(c, 1)


def test_subdivided_mesh_matches_trimesh_and_keeps_the_surface(sub1: tuple[Character, Character]) -> None:
    c, s = sub1
    m = trimesh.Trimesh(c.rest_vertices.astype(np.float64), c.faces, process=False)
    edges = m.edges_unique  # one new vertex per edge, the originals first and unchanged
    assert s.num_vertices == c.num_vertices + len(edges) and len(s.faces) == 4 * len(c.faces)
    assert_bitwise(s.rest_vertices[:c.num_vertices], c.rest_vertices, why="the original vertices are copied")
    new = s.rest_vertices[c.num_vertices:].astype(np.float64)
    mids = m.vertices[edges].mean(axis=1)
    # every new vertex is one edge's midpoint (float32 rounding of a float64 mean: half an ulp of the coordinate)
    order_new = np.lexsort(new.T[::-1])
    order_mid = np.lexsort(mids.T[::-1])
    np.testing.assert_allclose(new[order_new], mids[order_mid], rtol=0, atol=F32 * np.abs(mids).max())
    ms = trimesh.Trimesh(s.rest_vertices.astype(np.float64), s.faces, process=False)
    # midpoints lie on the flat triangles: the same area (float32 positions: relative error ~ a few eps32)
    assert abs(ms.area - m.area) <= 8 * F32 * m.area
    assert abs(ms.volume - m.volume) <= 8 * F32 * abs(m.volume) * 3
    assert ms.is_winding_consistent == m.is_winding_consistent


def test_subdivided_skin_weights_are_the_edge_means(sub1: tuple[Character, Character]) -> None:
    c, s = sub1
    w = s.dense_weights.astype(np.float64)
    sums = s.weights.astype(np.float64).sum(axis=1)
    # rows renormalised in float64, stored float32: each weight within half an ulp, the sum within K of them
    assert np.abs(sums - 1).max() <= s.weights.shape[1] * F32 and (s.weights >= 0).all()
    m = trimesh.Trimesh(c.rest_vertices.astype(np.float64), c.faces, process=False)
    edges = m.edges_unique
    # find each edge's new vertex by position (trimesh's own subdivision gives the same vertices in its order)
    tv, _ = trimesh.remesh.subdivide(m.vertices, m.faces)
    np.testing.assert_allclose(s.rest_vertices, tv, rtol=0, atol=F32 * np.abs(tv).max())
    e_tm = np.sort(trimesh.geometry.faces_to_edges(m.faces), axis=1)
    uniq, _ = trimesh.grouping.unique_rows(e_tm)
    pairs = e_tm[uniq]
    assert len(pairs) == len(edges)
    wc = c.dense_weights.astype(np.float64)
    expect = 0.5 * (wc[pairs[:, 0]] + wc[pairs[:, 1]])
    np.testing.assert_allclose(w[c.num_vertices:], expect, rtol=0, atol=2 * F32)
    n = s.rest_normals.astype(np.float64)
    assert np.abs(np.linalg.norm(n, axis=1) - 1).max() <= 4 * F32


def test_skinning_and_subdivision_commute_up_to_the_closed_form(sub1: tuple[Character, Character]) -> None:
    """skin(midpoint, mean weights) = mean of the skinned endpoints - 1/4 sum_j (w_a - w_b)_j R_j (p_a - p_b)."""
    c, s = sub1
    clip = next(iter(c.clips))
    poses = c.pose(clip)
    mats = poses.skin[[0, poses.num_frames // 2]]
    pos_c, _ = c.skin_mesh(mats)
    pos_s, _ = s.skin_mesh(mats)
    m = trimesh.Trimesh(c.rest_vertices.astype(np.float64), c.faces, process=False)
    e_tm = np.sort(trimesh.geometry.faces_to_edges(m.faces), axis=1)
    uniq, _ = trimesh.grouping.unique_rows(e_tm)
    a, b = e_tm[uniq].T
    wc = c.dense_weights.astype(np.float64)
    dw = wc[a] - wc[b]  # (E, J)
    dp = c.rest_vertices[a].astype(np.float64) - c.rest_vertices[b]  # (E, 3)
    scale = max(float(np.abs(pos_c).max()), float(np.abs(mats[..., :3, 3]).max()), 1.0)
    for f in range(len(mats)):
        posed_sub, _ = trimesh.remesh.subdivide(pos_c[f].astype(np.float64), c.faces)  # trimesh on the posed mesh
        corr = -0.25 * np.einsum("ej,jkl,el->ek", dw, mats[f, :, :3, :3], dp)
        got = pos_s[f, c.num_vertices:].astype(np.float64)
        # float32 skinning: each coordinate a J-term blend of 4x4 matrices applied to a point, rounded to float32
        # (|error| <= ~(4 + K) eps32 * scale for the skinned endpoints and the midpoint alike); 16 eps32 * scale
        # bounds the difference of three such values
        tol = 16 * F32 * scale
        np.testing.assert_allclose(got, posed_sub[c.num_vertices:] + corr, rtol=0, atol=tol)
        assert np.abs(corr).max() > 100 * tol  # the correction is real on a bending character: not a vacuous test
        # rigid pose: every joint the same transform: the correction vanishes and trimesh's subdivision is exact
    rigid = np.broadcast_to(mats[0, :1], mats[0].shape).copy()
    pc, _ = c.skin_mesh(rigid)
    ps, _ = s.skin_mesh(rigid)
    tv, _ = trimesh.remesh.subdivide(pc.astype(np.float64), c.faces)
    np.testing.assert_allclose(ps, tv, rtol=0, atol=16 * F32 * scale)


def test_subdivided_uvs_follow_the_corners(sub1: tuple[Character, Character], humanoid: Character) -> None:
    c, s = sub1
    assert s.uv is not None
    # the UVs are the corners' rest (x, y): a linear function, so the subdivided corners carry it exactly
    np.testing.assert_allclose(s.uv, s.rest_vertices[s.faces][..., :2], rtol=0,
                               atol=4 * F32 * float(np.abs(c.rest_vertices).max()))
    v, f, _, bary = subdivide_mesh(c.rest_vertices, c.faces, {}, 2)
    parent = c.rest_vertices[c.faces].astype(np.float64)[np.repeat(np.arange(len(c.faces)), 16)]
    np.testing.assert_allclose(np.einsum("fck,fkd->fcd", bary, parent), v[f], rtol=0,
                               atol=4 * np.finfo(np.float64).eps * float(np.abs(v).max()))
    assert subdivide_character(humanoid, 0) is humanoid
    with pytest.raises(PrtError, match="character.subdivide"):
        subdivide_character(humanoid, MAX_SUBDIVIDE + 1)


def test_low_poly_advice() -> None:
    assert low_poly_advice(LOW_POLY_VERTICES) is None and low_poly_advice(10 * LOW_POLY_VERTICES) is None
    for n in (1, 130, 290, LOW_POLY_VERTICES - 1):
        line = low_poly_advice(n)
        levels = suggested_levels(n)
        assert line is not None and "\n" not in line and f"character.subdivide: {levels}" in line
        assert (n * 4 ** levels >= LOW_POLY_VERTICES or levels == MAX_SUBDIVIDE) and n * 4 ** (levels - 1) < \
            LOW_POLY_VERTICES


def test_config_subdivide_key_is_bounded() -> None:
    cfg = RunConfig.model_validate({"name": "x", "character": {"subdivide": 2}})
    assert cfg.character.subdivide == 2
    with pytest.raises(ValueError, match="subdivide"):
        RunConfig.model_validate({"name": "x", "character": {"subdivide": MAX_SUBDIVIDE + 1}})


@pytest.mark.skipif(not (SHARED / "RiggedFigure.glb").is_file(), reason="../shared RiggedFigure.glb absent")
def test_rigged_figure_info_warns_and_config_subdivides(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from prt_torch.rig.load import load_character

    path = SHARED / "RiggedFigure.glb"
    assert main(["info", str(path), "--json"]) == 0
    out, err = capsys.readouterr()
    info = json.loads(out)
    assert info["vertices"] == 130 and info["low_poly"] == low_poly_advice(130)
    assert err.strip().splitlines() == [f"warning: {low_poly_advice(130)}"]
    assert main(["info", "builtin", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["low_poly"] is None and "warning" not in err
    (tmp_path / "c.yaml").write_text(f"name: rf\ncharacter:\n  source: {path}\n  subdivide: 2\n")
    cfg = load_config(tmp_path / "c.yaml")
    ch = load_character(cfg)
    m = trimesh.Trimesh(ch.rest_vertices, ch.faces, process=False)
    assert len(ch.faces) == 16 * 256 and ch.num_vertices >= LOW_POLY_VERTICES
    assert m.is_winding_consistent and np.abs(ch.weights.sum(axis=1) - 1).max() <= ch.weights.shape[1] * F32
