"""Clustered-PCA pose resampling (``random_mode: cpca``, seed 001 sec. 2) of prt_torch.rig.random_pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import prt_torch.rig.random_pose as rp
from prt_torch.bake.plan import RANDOM_CLIP, make_plan
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.rig import builtin
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.random_pose import fit_cpca, limit_angles, random_poses, sample_cpca
from tests.tolerance import assert_bitwise

TRAIN = ["walk", "run", "squat", "stretch", "jumping_jacks"]  # every built-in clip but wave


@pytest.fixture(scope="module")
def small() -> Character:
    """The built-in humanoid at density 0.05, 5 fps."""
    return builtin.make_character(0.05, fps=5.0)


def _rel(character: Character, local: np.ndarray) -> np.ndarray:
    """``(F, J, 3, 3)`` bind-relative rotations ``R_bind^T R_local``."""
    return np.swapaxes(character.bind_local[None, :, :3, :3], -1, -2) @ local[..., :3, :3]


# --- the linear algebra: clusters, principal subspaces, stratified coefficients --------------------------------------

def _low_rank_set(rng: np.random.Generator, n_per: int = 60, dim: int = 24) -> tuple[np.ndarray, list[tuple]]:
    """Two far-apart clusters of ``n_per`` points, ``mean + z @ V`` with 3-dim latents ``z`` -> ``(2 n_per, dim)``."""
    x, truth = [], []
    for c in range(2):
        mean = rng.normal(size=dim) + 20.0 * c
        basis = np.linalg.qr(rng.normal(size=(dim, 3)))[0].T  # (3, dim) orthonormal rows
        z = rng.uniform(-1, 1, size=(n_per, 3)) * np.array([3.0, 2.0, 1.0])
        x.append(mean + z @ basis)
        truth.append((mean, basis))
    return np.concatenate(x), truth


def test_cpca_reproduces_a_low_rank_pose_set() -> None:
    x, truth = _low_rank_set(np.random.default_rng(0))
    model = fit_cpca(x, clusters=2, components=8, random_state=0)
    assert model.num_clusters == 2
    # k-means recovers the generating clusters
    gen = np.repeat([0, 1], 60)
    assert {tuple(np.unique(gen[m])) for m in model.members} == {(0,), (1,)}
    n = 101
    smp = sample_cpca(model, n, np.random.default_rng(1))
    assert smp.features.shape == (n, 24)
    assert np.bincount(smp.cluster).tolist() == [51, 50]  # spread evenly, cluster order
    for c in range(2):
        sel = smp.cluster == c
        s = int(sel.sum())
        mean, basis = truth[int(gen[model.members[c][0]])]
        # the samples lie in the cluster's (generating) 3-dim affine subspace
        d = smp.features[sel] - mean
        np.testing.assert_allclose(d - (d @ basis.T) @ basis, 0.0, atol=1e-9)
        # 8 components, 3 carry variance: the other ranges are empty
        assert model.bases[c].shape == (8, 24)
        assert np.all(model.hi[c][3:] - model.lo[c][3:] < 1e-9)
        z = (smp.features[sel] - model.means[c]) @ model.bases[c].T
        lo, hi = model.lo[c], model.hi[c]
        assert np.all(z >= lo - 1e-9) and np.all(z <= hi + 1e-9)  # within the observed ranges
        # stratified: each of the s strata of every live component holds exactly one sample (a Latin hypercube)
        stratum = np.floor((z[:, :3] - lo[:3]) / (hi[:3] - lo[:3]) * s).astype(int)
        for k in range(3):
            assert sorted(stratum[:, k].tolist()) == list(range(s))
        # the observed coefficients fill the same ranges (the box is the data's, not a guess)
        np.testing.assert_allclose(model.coeffs[c].min(axis=0), lo)
        np.testing.assert_allclose(model.coeffs[c].max(axis=0), hi)
        # the base frames are the nearest members in PCA coefficients
        nearest = np.argmin(np.linalg.norm(z[:, None] - model.coeffs[c][None], axis=-1), axis=1)
        assert_bitwise(smp.base[sel], model.members[c][nearest], why='the base frames are copies of training members')


def _two_cluster_clips(c: Character, rng: np.random.Generator, n_per: int = 30) -> tuple[list[Clip], dict]:
    """Two clips of a rotation-space low-rank motion: clip A moves 3 joints about fixed axes from the bind pose, clip B
    moves 3 other joints about fixed axes from a far-away pose ``Q``; root translations mark the frames.

    A joint turning about a coordinate axis ``e`` has 6D features ``I + b K + c K^2`` (``b = sin``, ``c = 1 - cos``):
    rank 2 per joint, so each cluster's features span a 6-dim affine subspace (8 components hold it exactly), and
    every point of it (any ``b, c``) maps by Gram-Schmidt to a rotation about ``e`` again (left-multiplying by ``Q``
    commutes with Gram-Schmidt): the "manifold" the resampled poses must stay on."""
    j = c.num_joints
    bind = c.bind_local[:, :3, :3]
    q = Rotation.random(j, random_state=5).as_matrix()
    q = Rotation.from_rotvec(Rotation.from_matrix(q).as_rotvec() * 0.8).as_matrix()  # far, but not near 180 deg
    spec = {"A": ([6, 15, 19], np.tile(np.eye(3), (j, 1, 1))), "B": ([10, 3, 17], q)}
    axes = {jj: np.eye(3)[a] for jj, a in zip([6, 15, 19, 10, 3, 17], [0, 1, 2, 2, 0, 1], strict=True)}
    clips = []
    for ci, (name, (moving, base)) in enumerate(spec.items()):
        local = np.tile(c.bind_local, (n_per, 1, 1, 1))
        local[:, 1:, :3, :3] = bind[None, 1:] @ base[None, 1:]
        for jj, scale in zip(moving, (60.0, 35.0, 15.0), strict=True):
            ang = np.radians(scale) * rng.uniform(-1, 1, size=n_per)
            local[:, jj, :3, :3] = bind[jj] @ base[jj] @ Rotation.from_rotvec(ang[:, None] * axes[jj]).as_matrix()
        local[:, 0, :3, 3] = [ci, 0.0, 0.0]
        local[:, 0, 2, 3] = 0.01 * np.arange(n_per)
        clips.append(Clip(name, 5.0, local))
    return clips, {"spec": spec, "axes": axes}


def test_cpca_poses_stay_on_each_clusters_rotation_manifold(small: Character) -> None:
    c = replace(small, joint_limits=None)  # no clamp: the subspace is all that shapes the poses
    clips, info = _two_cluster_clips(c, np.random.default_rng(3))
    out = random_poses(c, 50, seed=4, mode="cpca", base_clips=clips, cpca_clusters=2, cpca_components=8)
    rel = _rel(c, out.local)
    in_b = out.local[:, 0, 0, 3] == 1.0  # root from a training frame of the cluster (x = clip index)
    assert in_b.sum() == 25
    train_roots = np.concatenate([k.local[:, 0] for k in clips])
    assert all(np.any(np.all(np.isclose(train_roots, r, atol=0, rtol=0), axis=(1, 2))) for r in out.local[:, 0])
    for name, sel in (("A", ~in_b), ("B", in_b)):
        moving, base = info["spec"][name]
        for jj in range(1, c.num_joints):
            r = np.swapaxes(base[jj], -1, -2)[None] @ rel[sel, jj]  # (s, 3, 3) relative to the cluster's pose
            if jj in moving:  # a rotation about the joint's own axis: the Gram-Schmidt image of the subspace
                u = info["axes"][jj]
                np.testing.assert_allclose(r @ u, np.broadcast_to(u, (int(sel.sum()), 3)), atol=1e-9)
                assert np.ptp(Rotation.from_matrix(r).magnitude()) > np.radians(5)  # and it does move
            else:  # joints the cluster never moves stay put
                np.testing.assert_allclose(r, np.broadcast_to(np.eye(3), r.shape), atol=1e-9)


# --- valid rotations, joint limits, determinism ---------------------------------------------------------------------

def test_cpca_poses_are_rotations_within_the_humanoids_limits(humanoid: Character) -> None:
    out = random_poses(humanoid, 300, seed=0, mode="cpca", base_clips=TRAIN)
    assert out.local.shape == (300, humanoid.num_joints, 4, 4)
    r = out.local[:, 1:, :3, :3]
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    ang = limit_angles(humanoid, out.local)[:, 1:]  # non-root joints (the root keeps its training frame)
    lim = humanoid.joint_limits[1:]
    assert np.all(ang >= lim[None, ..., 0] - 1e-9) and np.all(ang <= lim[None, ..., 1] + 1e-9)
    # root transform and every translation: one training frame's
    frames = np.concatenate([humanoid.clips[k].local for k in TRAIN])
    assert all(np.any(np.all(np.isclose(frames[:, 0], f[0], atol=0, rtol=0), axis=(1, 2))) for f in out.local)
    assert_bitwise(out.local[:, 1:, :3, 3], np.broadcast_to(humanoid.bind_local[1:, :3, 3],
                                                                           out.local[:, 1:, :3, 3].shape),
                   why='joint translations are copied from the bind pose')
    # the poses vary (8 clusters, not copies of training frames)
    assert np.unique(np.round(out.local[:, 1:, :3, :3], 6).reshape(300, -1), axis=0).shape[0] == 300


def test_the_clamp_applies_only_to_characters_with_limits(small: Character) -> None:
    free = random_poses(replace(small, joint_limits=None), 200, seed=2, mode="cpca", base_clips=TRAIN)
    held = random_poses(small, 200, seed=2, mode="cpca", base_clips=TRAIN)
    ang = limit_angles(small, free.local)[:, 1:]
    lim = small.joint_limits[1:]
    inside = np.all((ang >= lim[None, ..., 0]) & (ang <= lim[None, ..., 1]), axis=-1)  # (n, J-1)
    assert not inside.all()  # resampling leaves the limits somewhere ...
    r_free, r_held = free.local[:, 1:, :3, :3], held.local[:, 1:, :3, :3]
    np.testing.assert_allclose(r_held[inside], r_free[inside], atol=1e-9)  # ... and only there the clamp acts
    assert not np.allclose(r_held[~inside], r_free[~inside], atol=1e-6)


def test_cpca_is_deterministic_for_a_seed(small: Character) -> None:
    a = random_poses(small, 64, seed=11, mode="cpca", base_clips=TRAIN, cpca_clusters=4, cpca_components=5)
    b = random_poses(small, 64, seed=11, mode="cpca", base_clips=TRAIN, cpca_clusters=4, cpca_components=5)
    assert_bitwise(a.local, b.local, why='the same seeded sampler twice')
    other = random_poses(small, 64, seed=12, mode="cpca", base_clips=TRAIN, cpca_clusters=4, cpca_components=5)
    assert not np.allclose(a.local, other.local)


def test_repeated_frames_lower_the_cluster_count(small: Character) -> None:
    still = Clip("still", 5.0, np.tile(small.clips["walk"].local[2], (10, 1, 1, 1)))
    out = random_poses(small, 7, seed=0, mode="cpca", base_clips=[still], cpca_clusters=8)
    np.testing.assert_allclose(out.local, np.broadcast_to(still.local[0], out.local.shape), atol=1e-9)


# --- training sources only -------------------------------------------------------------------------------------------

def test_plan_clusters_exactly_the_training_frames(small: Character, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []

    def spy(features: np.ndarray, *args: object, **kwargs: object) -> rp.CpcaModel:
        seen.append(np.array(features))
        return fit(features, *args, **kwargs)

    fit = rp.fit_cpca
    monkeypatch.setattr(rp, "fit_cpca", spy)
    cfg = config_from_dict(_cfg(train_clips=["stretch", {"clip": "walk", "frames": ":6"}],
                                heldout_clips=[{"clip": "walk", "frames": "6:"}, "wave"]))
    plan = make_plan(cfg, character=small)
    assert len(seen) == 1
    train = np.isin(plan.clip_id, [plan.clip_names.index(n) for n in ("stretch", "walk[:6]")])
    assert seen[0].shape == (int(train.sum()), small.feature_width)
    np.testing.assert_allclose(seen[0], plan.pose[train], atol=1e-6)  # the training frames, in order, nothing else


# --- config and plan ------------------------------------------------------------------------------------------------

def _cfg(**character: object) -> dict:
    ch = {"source": "builtin", "density": 0.05, "fps": 5.0, "train_clips": ["stretch", "squat"],
          "heldout_clips": ["wave"], "random_poses": 24, "seed": 1, "random_mode": "cpca"}
    ch.update(character)
    return {"name": "t", "character": ch}


def test_plan_threads_the_cpca_settings(small: Character) -> None:
    plan = make_plan(config_from_dict(_cfg(random_cpca_clusters=3, random_cpca_components=5)), character=small)
    rid = plan.clip_names.index(RANDOM_CLIP)
    expected = random_poses(small, 24, seed=1, fps=5.0, mode="cpca", base_clips=["stretch", "squat"],
                            cpca_clusters=3, cpca_components=5)
    np.testing.assert_allclose(plan.pose[plan.clip_id == rid], small.pose(expected).features, atol=1e-6)
    default = config_from_dict(_cfg()).character
    assert (default.random_cpca_clusters, default.random_cpca_components) == (8, 8)


@pytest.mark.parametrize("key,value", [("random_cpca_clusters", 0), ("random_cpca_clusters", 65),
                                       ("random_cpca_components", 0), ("random_cpca_components", 55)])
def test_config_bounds(key: str, value: int) -> None:
    with pytest.raises(PrtError, match=key):
        config_from_dict(_cfg(**{key: value}))


def _one_line_error(match: str, fn: object, *args: object, **kwargs: object) -> None:
    with pytest.raises(PrtError, match=match) as e:
        fn(*args, **kwargs)  # type: ignore[operator]
    assert "\n" not in str(e.value)


def test_bad_parameters_are_one_line_errors(small: Character) -> None:
    _one_line_error("feature dimension 120", random_poses, small, 4, mode="cpca", base_clips=TRAIN,
                    cpca_components=121)
    five = Clip("five", 5.0, small.clips["walk"].local[:5])
    _one_line_error("cpca_clusters=8 exceeds the 5 training frames", random_poses, small, 4, mode="cpca",
                    base_clips=[five])
    _one_line_error("need training clips", random_poses, small, 4, mode="cpca")
    _one_line_error("need training clips", make_plan, config_from_dict(_cfg(train_clips=[])), character=small)
    _one_line_error("cpca_clusters must be >= 1", random_poses, small, 4, mode="cpca", base_clips=TRAIN,
                    cpca_clusters=0)
    _one_line_error("cpca_components must be >= 1", random_poses, small, 4, mode="cpca", base_clips=TRAIN,
                    cpca_components=0)
