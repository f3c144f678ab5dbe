"""Sphere blockers: coverage of the rest mesh, allotment, rigid posing with the bones (LBS as reference),
file round trip, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.blockers import SphereSet, fit_spheres, pose_spheres, vertex_bones
from prt_torch.errors import PrtError
from tests.tolerance import assert_bitwise


@pytest.fixture(scope="module")
def character():  # noqa: ANN201
    from prt_torch.rig.builtin import make_character

    return make_character(density=0.25)


@pytest.fixture(scope="module")
def spheres(character) -> SphereSet:  # noqa: ANN001
    return fit_spheres(character, n_spheres=40, radius_quantile=0.8)


def test_covers_the_rest_mesh(character, spheres: SphereSet) -> None:  # noqa: ANN001
    from scipy.spatial.distance import cdist

    d = cdist(character.rest_vertices.astype(np.float64), spheres.center.astype(np.float64))
    inside = (d <= spheres.radius[None].astype(np.float64) * (1 + 1e-5)).any(1)
    # radius rule: at least the quantile q of every cluster lies inside its own sphere, so of the mesh too
    assert inside.mean() >= spheres.radius_quantile - 1e-3
    full = fit_spheres(character, n_spheres=40, radius_quantile=1.0)
    d = cdist(character.rest_vertices.astype(np.float64), full.center.astype(np.float64))
    assert (d <= full.radius[None] * (1 + 1e-5)).any(1).all()
    # smaller quantile, smaller spheres (thin limbs not over-covered)
    assert np.median(spheres.radius) < np.median(full.radius)


def test_allotment_follows_vertex_counts(character, spheres: SphereSet) -> None:  # noqa: ANN001
    vb = vertex_bones(character.joints, character.weights)
    counts = np.bincount(vb, minlength=character.num_joints)
    per_bone = np.bincount(spheres.bone, minlength=character.num_joints)
    assert spheres.num_spheres == 40 and per_bone.sum() == 40
    assert ((per_bone >= 1) == (counts > 0)).all()
    share = counts / counts.sum() * 40
    # the floor of one sphere per bone moves a few spheres off the largest bones, never more than the floor needs
    floor_need = np.clip(1 - share[counts > 0], 0, None).sum()
    assert np.abs(per_bone - share)[counts > 0].max() < 1 + floor_need
    big, small = np.meshgrid(counts, counts, indexing="ij")  # monotone: more vertices, never fewer spheres
    pb, ps = np.meshgrid(per_bone, per_bone, indexing="ij")
    assert (pb[big > small] >= ps[big > small]).all()
    # fewer spheres than bones: k-means over the whole mesh, still the requested count
    few = fit_spheres(character, n_spheres=5)
    assert few.num_spheres == 5


def test_spheres_move_rigidly_with_their_bones(character, spheres: SphereSet) -> None:  # noqa: ANN001
    poses = character.pose(next(iter(character.clips)))
    skin = poses.skin[::7]
    centers = pose_spheres(spheres, skin)
    assert centers.shape == (skin.shape[0], spheres.num_spheres, 3) and centers.dtype == np.float32
    pos, _ = character.skin_mesh(skin)  # the character's own LBS is the reference
    w = character.dense_weights
    for s in range(0, spheres.num_spheres, 5):
        rigid = np.flatnonzero(w[:, spheres.bone[s]] > 0.999)[:20]
        if rigid.size == 0:
            continue
        rest = np.linalg.norm(character.rest_vertices[rigid] - spheres.center[s], axis=1)
        posed = np.linalg.norm(pos[:, rigid] - centers[:, s, None], axis=2)
        assert np.allclose(posed, rest[None], atol=1e-4)
    # an arbitrary rigid motion of every bone moves every centre by it
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = q, [0.3, -1.0, 2.0]
    moved = pose_spheres(spheres, np.repeat(m[None], character.num_joints, 0))
    assert np.allclose(moved, spheres.center @ q.T + m[:3, 3], atol=1e-5)


def test_save_load_round_trip(tmp_path: Path, spheres: SphereSet) -> None:
    spheres.save(tmp_path / "b.npz")
    back = SphereSet.load(tmp_path / "b.npz")
    np.testing.assert_array_equal(back.bone, spheres.bone)
    assert_bitwise(back.center, spheres.center, why="npz round trip")
    assert_bitwise(back.radius, spheres.radius, why="npz round trip")
    assert back.radius_quantile == spheres.radius_quantile
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(PrtError, match="not a sphere set"):
        SphereSet.load(tmp_path / "bad.npz")


@pytest.mark.parametrize("kwargs,match", [({"n_spheres": 0}, "sphere count"), ({"n_spheres": -3}, "sphere count"),
                                          ({"n_spheres": 2.5}, "sphere count"),
                                          ({"radius_quantile": 1.5}, "radius_quantile")])
def test_bad_input_is_one_line(character, kwargs: dict, match: str) -> None:  # noqa: ANN001
    with pytest.raises(PrtError, match=match) as e:
        fit_spheres(character, **kwargs)
    assert "\n" not in str(e.value)


def test_bad_pose_input(spheres: SphereSet) -> None:
    with pytest.raises(PrtError, match="skin matrices"):
        pose_spheres(spheres, np.eye(4)[None])  # too few joints
    bad = np.repeat(np.eye(4)[None], 30, 0)
    bad[0, 0, 0] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        pose_spheres(spheres, bad)
    with pytest.raises(PrtError, match="centres"):
        SphereSet(np.array([0]), np.zeros((2, 3)), np.ones(1))
