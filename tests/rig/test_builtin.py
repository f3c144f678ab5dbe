"""The built-in procedural humanoid: surface, skeleton, weights, motions, random poses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from prt_torch.errors import PrtError
from prt_torch.rig import builtin
from prt_torch.rig.character import Character
from prt_torch.rig.mesh import vertex_normals
from prt_torch.rig.random_pose import random_poses
from tests.tolerance import assert_bitwise

REQUIRED = ["pelvis", "spine", "chest", "neck", "head"] + [
    f"{j}_{s}" for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle") for s in "lr"]
ARM = [f"{j}_{s}" for j in ("shoulder", "elbow", "wrist") for s in "lr"]
TORSO = ["pelvis", "spine", "chest"]


def test_surface_is_closed_manifold_and_outward(humanoid: Character) -> None:
    m = trimesh.Trimesh(humanoid.rest_vertices, humanoid.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.euler_number == 2 and m.body_count == 1  # one genus-0 surface
    assert 0.04 < m.volume < 0.09  # m^3: a ~60 kg body, positive = outward faces
    fn = m.face_normals
    vn = humanoid.rest_normals[humanoid.faces].mean(1)
    assert np.mean((fn * vn).sum(1) > 0.5) > 0.99
    # smooth surface: the vertex normals (implicit-function gradients) match the mesh's own smooth normals,
    # and adjacent faces bend little (at ~3k vertices limbs of 3-5 cm radius get ~2.5 cm edges)
    mesh_vn = vertex_normals(humanoid.rest_vertices, humanoid.faces)
    assert np.quantile((mesh_vn * humanoid.rest_normals).sum(1), 0.01) > 0.95
    adj = m.face_adjacency
    cos = (fn[adj[:, 0]] * fn[adj[:, 1]]).sum(1)
    assert np.quantile(cos, 0.01) > 0.5 and np.median(cos) > 0.97


def test_proportions_and_skeleton(humanoid: Character) -> None:
    v = humanoid.rest_vertices
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert 1.7 < v[:, 2].max() < 1.9
    assert set(REQUIRED) <= set(humanoid.joint_names) and humanoid.num_joints >= 18
    bw = humanoid.pose(humanoid.bind_clip()).world[0]
    pos = {n: bw[i, :3, 3] for i, n in enumerate(humanoid.joint_names)}
    assert pos["toe_l"][1] < pos["ankle_l"][1]  # faces -y
    assert pos["elbow_l"][0] > 0 > pos["elbow_r"][0]  # its left is +x
    assert pos["head"][2] > pos["neck"][2] > pos["chest"][2] > pos["pelvis"][2] > pos["knee_l"][2]
    np.testing.assert_allclose(np.linalg.inv(humanoid.inverse_bind), bw, atol=1e-12)
    # every joint lies inside the body
    m = trimesh.Trimesh(v, humanoid.faces, process=False)
    inner = [n for n in humanoid.joint_names if not n.startswith("toe")]
    assert m.contains(np.array([pos[n] for n in inner])).all()


def test_vertex_count_scales_with_density(humanoid: Character) -> None:
    assert 2500 <= humanoid.num_vertices <= 3500
    full = builtin.make_character(1.0)
    assert 10000 <= full.num_vertices <= 12500
    assert 3.3 < full.num_vertices / humanoid.num_vertices < 4.7


@pytest.mark.parametrize("density", [0.05, 0.5])
def test_other_densities_closed_genus_zero(density: float) -> None:
    # 0.05 is below the finest grid that resolves wrists and toes: extracted finer, then decimated
    c = builtin.make_character(density)
    assert 0.6 < c.num_vertices / (density * 11500) < 1.4
    m = trimesh.Trimesh(c.rest_vertices, c.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2 and m.body_count == 1
    assert 0.045 < m.volume < 0.07


def test_deterministic(humanoid: Character) -> None:
    again = builtin._build.__wrapped__(0.25)  # bypass the cache
    for a, b in zip(again, builtin._build(0.25), strict=True):
        assert_bitwise(a, b, why='the same build run twice')
    assert builtin.make_character(0.25).content_hash() == humanoid.content_hash()


def test_smooth_skin_weights(humanoid: Character) -> None:
    w = humanoid.dense_weights
    np.testing.assert_allclose(w.sum(1), 1, atol=1e-5)
    assert humanoid.weights.shape[1] == 4
    edges = trimesh.Trimesh(humanoid.rest_vertices, humanoid.faces, process=False).edges_unique
    length = np.linalg.norm(humanoid.rest_vertices[edges[:, 0]] - humanoid.rest_vertices[edges[:, 1]], axis=1)
    grad = np.abs(w[edges[:, 0]] - w[edges[:, 1]]).sum(1) / length  # L1 weight change per metre
    assert grad.max() < 40 and np.quantile(grad, 0.99) < 25 and np.median(grad) < 8  # transitions over >= 3 cm
    # blended across the elbow, rigid mid-bone
    bw = humanoid.pose(humanoid.bind_clip()).world[0]
    idx = {n: i for i, n in enumerate(humanoid.joint_names)}
    tree = cKDTree(humanoid.rest_vertices)
    _, near_elbow = tree.query(bw[idx["elbow_l"], :3, 3], k=20)
    assert np.all(w[near_elbow][:, [idx["shoulder_l"], idx["elbow_l"]]].sum(1) > 0.8)
    assert np.all(w[near_elbow][:, idx["shoulder_l"]] > 0.1) and np.all(w[near_elbow][:, idx["elbow_l"]] > 0.1)
    mid = 0.5 * (bw[idx["knee_l"], :3, 3] + bw[idx["ankle_l"], :3, 3])
    _, near_shin = tree.query(mid, k=10)
    assert np.all(w[near_shin][:, idx["knee_l"]] > 0.95)


def test_clips(humanoid: Character) -> None:
    assert list(humanoid.clips) == ["walk", "run", "jumping_jacks", "squat", "wave", "stretch"]
    for name, clip in humanoid.clips.items():
        assert clip.fps == 30.0 and 1.0 <= clip.duration <= 4.0, name
        p = humanoid.pose(name)
        # continuous motion: no joint turns more than 25 degrees between frames
        rel = np.swapaxes(p.local[:-1, :, :3, :3], -1, -2) @ p.local[1:, :, :3, :3]
        ang = np.degrees(Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude())
        assert ang.max() < 25, name
        pos, _ = humanoid.skin_mesh(p)
        low = pos[..., 2].min(1)
        assert low.min() > -0.03 and low.min() < 0.02, name  # on the ground, never below it
        if name in ("walk", "squat", "wave", "stretch"):
            assert low.max() < 0.03, name  # feet stay planted


def _min_distance(pos: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float(cKDTree(pos[b]).query(pos[a])[0].min())


def test_motions_exercise_self_shadowing(humanoid: Character) -> None:
    idx = {n: i for i, n in enumerate(humanoid.joint_names)}
    dom = np.array(humanoid.joint_names)[humanoid.dense_weights.argmax(1)]
    arm = np.isin(dom, ARM)
    torso = np.isin(dom, TORSO)
    walk = humanoid.pose("walk")
    pos, _ = humanoid.skin_mesh(walk)
    arm_r = arm & (humanoid.rest_vertices[:, 0] < 0)
    # arms swing close beside the torso
    assert min(_min_distance(pos[f], arm_r, torso) for f in range(0, walk.num_frames, 5)) < 0.05
    for clip in ("walk", "run"):
        w = humanoid.pose(clip).world
        dy = w[:, idx["ankle_l"], 1, 3] - w[:, idx["ankle_r"], 1, 3]
        assert dy.min() < -0.2 and dy.max() > 0.2, clip  # the legs pass each other
    st = humanoid.pose("stretch").world
    assert np.any(st[:, idx["wrist_l"], 2, 3] > st[:, idx["head"], 2, 3] + 0.2)  # arms overhead
    assert np.any(st[:, idx["head"], 2, 3] < st[0, idx["head"], 2, 3] - 0.3)  # bending forward
    sq = humanoid.pose("squat").world
    assert sq[:, idx["pelvis"], 2, 3].min() < sq[0, idx["pelvis"], 2, 3] - 0.3
    jj = humanoid.pose("jumping_jacks").world
    assert np.any(jj[:, idx["wrist_r"], 2, 3] > jj[:, idx["head"], 2, 3])
    wave = humanoid.pose("wave").world
    assert np.any(wave[:, idx["wrist_r"], 2, 3] > wave[:, idx["head"], 2, 3])


def test_random_poses_within_joint_limits(humanoid: Character) -> None:
    clip = random_poses(humanoid, 64, seed=3)
    assert clip.num_frames == 64
    rel = np.swapaxes(humanoid.bind_local[None, :, :3, :3], -1, -2) @ clip.local[..., :3, :3]
    # independent decomposition: intrinsic X-Z-Y Euler angles (R = Rx Rz Ry), unique in these ranges
    xzy = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler("XZY", degrees=True).reshape(64, -1, 3)
    angles = xzy[..., [0, 2, 1]]  # (a_x, a_y, a_z)
    lim = builtin.JOINT_LIMITS_DEG
    assert np.all(angles >= lim[None, :, :, 0] - 1e-6) and np.all(angles <= lim[None, :, :, 1] + 1e-6)
    span = angles.max(0) - angles.min(0)
    width = lim[..., 1] - lim[..., 0]
    assert np.all(span[width > 0] > 0.5 * width[width > 0])  # the range is actually explored
    assert_bitwise(clip.local[:, 0], np.tile(humanoid.bind_local[0], (64, 1, 1)),
                   why='the root keeps the bind transform: a copy')
    assert_bitwise(random_poses(humanoid, 64, seed=3).local, clip.local, why='the same seeded sampler twice')
    assert not np.allclose(random_poses(humanoid, 64, seed=4).local, clip.local)
    assert humanoid.pose(clip).features.shape == (64, humanoid.feature_width)


def test_random_poses_fallback_perturbs_clip_frames(humanoid: Character) -> None:
    c = replace(humanoid, joint_limits=None)
    clip = random_poses(c, 20, seed=0, perturb_deg=15.0, base_clips=sorted(c.clips))  # sources: explicit only
    frames = np.concatenate([k.local for k in c.clips.values()])[:, 1:, :3, :3]  # non-root joints
    got = clip.local[:, 1:, :3, :3]
    for f in range(20):
        rel = np.swapaxes(frames, -1, -2) @ got[f][None]
        ang = np.degrees(Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude()).reshape(len(frames), -1)
        assert ang.max(1).min() <= 15.0 + 1e-6


def test_bad_arguments(humanoid: Character) -> None:
    with pytest.raises(PrtError, match="density"):
        builtin.make_character(0.0)
    with pytest.raises(PrtError, match="unknown built-in motion"):
        builtin.make_clip("moonwalk", humanoid.bind_local, humanoid.parents)
    with pytest.raises(PrtError, match="random poses"):
        random_poses(humanoid, 0)


def test_arms_shadow_the_torso_by_ray_casting(humanoid: Character) -> None:
    """Ground truth by Embree: rays along the normals of the torso's flanks hit the arms when they hang
    down (walk) and escape when they are raised (jumping jacks)."""
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    dom = np.array(humanoid.joint_names)[humanoid.dense_weights.argmax(1)]
    flank_part = np.isin(dom, ["chest", "spine"])

    def occluded(clip: str) -> np.ndarray:
        p = humanoid.pose(clip)
        pos, nrm = humanoid.skin_mesh(p)
        out = []
        for f in range(0, p.num_frames, 3):
            flank = flank_part & (np.abs(nrm[f][:, 0]) > 0.8)
            mesh = trimesh.Trimesh(pos[f], humanoid.faces, process=False)
            hit = RayMeshIntersector(mesh).intersects_any(pos[f][flank] + 1e-3 * nrm[f][flank], nrm[f][flank])
            out.append(hit.mean())
        return np.array(out)

    walk, jacks = occluded("walk"), occluded("jumping_jacks")
    assert walk.min() > 0.15
    assert jacks.min() < 0.02 and jacks.max() > 0.25
