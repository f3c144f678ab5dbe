"""Sparse / trajectory random poses (prt_torch.rig.random_pose) and their config path (bake plan)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from prt_torch.bake.plan import RANDOM_CLIP, make_plan
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.rig import builtin
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.random_pose import compose_limit_angles, joint_chains, limit_angles, random_poses
from tests.tolerance import assert_bitwise

N = 96


def _limit_angles(humanoid: Character, local: np.ndarray) -> np.ndarray:
    """``(F, J, 3)`` bind-relative ``(a_x, a_y, a_z)`` degrees by scipy's intrinsic X-Z-Y Euler decomposition."""
    rel = np.swapaxes(humanoid.bind_local[None, :, :3, :3], -1, -2) @ local[..., :3, :3]
    xzy = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler("XZY", degrees=True).reshape(*local.shape[:2], 3)
    return xzy[..., [0, 2, 1]]


def test_joint_chains_of_the_humanoid() -> None:
    names = builtin.JOINT_NAMES
    parents = np.array([-1 if p is None else names.index(p) for _, p, _ in builtin._joint_table()])
    got = [[names[j] for j in c] for c in joint_chains(parents)]
    expected = [["spine", "chest"], ["neck", "head"]]
    expected += [[f"{j}_{s}" for j in ("clavicle", "shoulder", "elbow", "wrist")] for s in "lr"]
    expected += [[f"{j}_{s}" for j in ("hip", "knee", "ankle", "toe")] for s in "lr"]
    assert got == expected


def test_joint_chains_partition_any_tree() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        j = int(rng.integers(2, 30))
        parents = np.array([-1] + [int(rng.integers(0, c)) for c in range(1, j)])
        chains = joint_chains(parents)
        flat = sorted(x for c in chains for x in c)
        assert flat == list(range(1, j))  # every non-root joint exactly once
        for c in chains:
            assert all(parents[b] == a for a, b in zip(c[:-1], c[1:], strict=False))  # a parent -> child path
            assert all(np.count_nonzero(parents == a) == 1 for a in c[:-1])  # no branch inside a chain


def test_sparse_moves_few_chains_within_limits_from_training_bases(humanoid: Character) -> None:
    clip = random_poses(humanoid, N, seed=5, mode="sparse", base_clips=["stretch", "squat"], max_chains=2)
    assert clip.num_frames == N
    chains = joint_chains(humanoid.parents)
    bases = np.concatenate([humanoid.bind_local[None], humanoid.clips["stretch"].local,
                            humanoid.clips["squat"].local])  # (B, J, 4, 4)
    lim = builtin.JOINT_LIMITS_DEG
    angles = _limit_angles(humanoid, clip.local)
    n_from_clip = 0
    for f in range(N):
        # the base: the candidate agreeing exactly with the most joints (root included)
        same = np.all(np.isclose(bases, clip.local[f][None], rtol=0, atol=1e-12), axis=(-1, -2))  # (B, J)
        b = int(np.argmax(same.sum(1)))
        assert same[b, 0]  # the root keeps the base transform
        n_from_clip += b > 0
        moved = [c for c in chains if not same[b, c].all()]
        assert 1 <= len(moved) <= 2
        for c in moved:  # moved chains: every joint within the limits
            a = angles[f, c]
            assert np.all(a >= lim[c, :, 0] - 1e-6) and np.all(a <= lim[c, :, 1] + 1e-6)
        assert sum(len(c) for c in moved) + same[b].sum() == humanoid.num_joints
    assert 0.3 * N < n_from_clip < 0.7 * N  # base_clip_prob = 0.5
    # every chain gets moved somewhere, covering most of each joint's range
    span = angles.max(0) - angles.min(0)
    width = lim[..., 1] - lim[..., 0]
    assert np.all(span[1:][width[1:] > 0] > 0.4 * width[1:][width[1:] > 0])


def test_sparse_is_deterministic_and_never_uses_other_clips(humanoid: Character) -> None:
    a = random_poses(humanoid, 40, seed=2, mode="sparse", base_clips=["run"], base_clip_prob=1.0)
    assert_bitwise(a.local, random_poses(humanoid, 40, seed=2, mode="sparse", base_clips=["run"],
                                                        base_clip_prob=1.0).local, why='the same seeded sampler twice')
    assert not np.allclose(a.local, random_poses(humanoid, 40, seed=3, mode="sparse", base_clips=["run"],
                                                 base_clip_prob=1.0).local)
    # all bases are run frames: the root of every pose is a run frame's root, never a wave frame's
    run_roots = humanoid.clips["run"].local[:, 0]
    wave_roots = humanoid.clips["wave"].local[:, 0]
    d_run = np.abs(a.local[:, None, 0] - run_roots[None]).max(axis=(-1, -2)).min(1)
    d_wave = np.abs(a.local[:, None, 0] - wave_roots[None]).max(axis=(-1, -2)).min(1)
    assert np.all(d_run == 0) and np.all(d_wave > 0)
    # no base clips: the root and the unmoved joints stay at the bind pose
    b = random_poses(humanoid, 40, seed=2, mode="sparse")
    assert_bitwise(b.local[:, 0], np.tile(humanoid.bind_local[0], (40, 1, 1)),
                   why='the root keeps the bind transform: a copy')


def test_sparse_trajectories_are_slerps_between_key_poses(humanoid: Character) -> None:
    seg = 5
    n = 4 * seg + 1
    traj = random_poses(humanoid, n, seed=7, mode="sparse", segment=seg, base_clips=["stretch"])
    assert traj.num_frames == n
    r = traj.local[..., :3, :3]
    for k in range(4):
        key_a, key_b = r[k * seg], r[(k + 1) * seg]
        total = Rotation.from_matrix(np.swapaxes(key_a, -1, -2) @ key_b).magnitude()  # (J,)
        steps = Rotation.from_matrix(np.swapaxes(r[k * seg:(k + 1) * seg], -1, -2) @ r[k * seg + 1:(k + 1) * seg + 1]
                                     ).magnitude()  # (seg, J) per-frame step angles
        np.testing.assert_allclose(steps, np.broadcast_to(total / seg, steps.shape), atol=1e-9)  # constant speed
    t = traj.local[..., :3, 3]  # translations: linear between keys (second differences vanish inside a segment)
    np.testing.assert_allclose(t[2:seg + 1] - 2 * t[1:seg] + t[:seg - 1], 0.0, atol=1e-12)


def test_sparse_without_limits_perturbs_chains_of_clip_frames(humanoid: Character) -> None:
    c = replace(humanoid, joint_limits=None)
    clip = random_poses(c, 30, seed=0, mode="sparse", base_clips=["squat"], base_clip_prob=1.0, perturb_deg=12.0)
    frames = c.clips["squat"].local[:, :, :3, :3]
    rel = np.swapaxes(frames[:, None], -1, -2) @ clip.local[None, :, :, :3, :3]  # (Fs, N, J, 3, 3)
    ang = np.degrees(Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude()).reshape(rel.shape[:3])
    best = (ang < 1e-9).sum(-1).argmax(0)  # the base frame of each pose: most joints unchanged
    per_joint = ang[best, np.arange(30)]  # (N, J)
    assert np.all(per_joint <= 12.0 + 1e-6)
    assert np.all((per_joint > 1e-9).sum(1) <= 3 * 4)  # at most max_chains=3 chains of <= 4 joints move


def test_limit_angles_invert_the_composition(humanoid: Character) -> None:
    rng = np.random.default_rng(0)
    ang = np.radians(rng.uniform(-80.0, 80.0, (7, humanoid.num_joints, 3)))
    ang[..., 2] = np.clip(ang[..., 2], -1.4, 1.4)  # XZY Euler angles are unique for |a_z| < 90 degrees
    local = np.tile(humanoid.bind_local, (7, 1, 1, 1))
    # the composition by explicit axis-angle matrices from scipy (independent of compose_limit_angles)
    rx, ry, rz = (Rotation.from_rotvec(np.einsum("...,k->...k", ang[..., i], np.eye(3)[i]).reshape(-1, 3))
                  .as_matrix().reshape(7, -1, 3, 3) for i in (0, 1, 2))
    local[..., :3, :3] = humanoid.bind_local[:, :3, :3] @ rx @ rz @ ry
    np.testing.assert_allclose(compose_limit_angles(ang), rx @ rz @ ry, atol=1e-12)
    np.testing.assert_allclose(limit_angles(humanoid, local), ang, atol=1e-9)


def test_near_base_concentrates_moved_joints_near_the_base(humanoid: Character) -> None:
    lim = np.radians(builtin.JOINT_LIMITS_DEG)
    far = random_poses(humanoid, 400, seed=4, mode="sparse", near_base=0.0)  # bind bases: angles 0
    near = random_poses(humanoid, 400, seed=4, mode="sparse", near_base=1.0)
    a_far, a_near = np.abs(limit_angles(humanoid, far.local)), np.abs(limit_angles(humanoid, near.local))
    a = limit_angles(humanoid, near.local)
    assert np.all(a >= lim[None, :, :, 0] - 1e-9) and np.all(a <= lim[None, :, :, 1] + 1e-9)  # bind is inside
    # moved joints: |angle| is f * |uniform| with f ~ U(0, 1): half the mean of the uniform sampler's
    m_far = a_far[a_far > 1e-9].mean()
    m_near = a_near[a_near > 1e-9].mean()
    assert 0.4 * m_far < m_near < 0.6 * m_far


def test_bad_arguments(humanoid: Character) -> None:
    with pytest.raises(PrtError, match="random pose mode"):
        random_poses(humanoid, 4, mode="grid")
    with pytest.raises(PrtError, match="segment"):
        random_poses(humanoid, 4, mode="sparse", segment=0)
    with pytest.raises(PrtError, match="max_chains"):
        random_poses(humanoid, 4, mode="sparse", max_chains=0)
    with pytest.raises(PrtError, match="base_clip_prob"):
        random_poses(humanoid, 4, mode="sparse", base_clip_prob=1.5)
    with pytest.raises(PrtError, match="unknown clip 'moonwalk'"):
        random_poses(humanoid, 4, mode="sparse", base_clips=["moonwalk"])
    with pytest.raises(PrtError, match="near_base"):
        random_poses(humanoid, 4, mode="sparse", near_base=-0.1)
    with pytest.raises(PrtError, match="perturb_deg"):
        random_poses(humanoid, 4, perturb_deg=float("nan"))


def _cfg(**character: object) -> dict:
    ch = {"source": "builtin", "density": 0.05, "fps": 5.0, "train_clips": ["stretch"], "heldout_clips": ["wave"],
          "random_poses": 24, "seed": 1}
    ch.update(character)
    return {"name": "t", "character": ch}


def test_plan_uses_the_sparse_sampler_with_training_bases_only() -> None:
    cfg = config_from_dict(_cfg(random_mode="sparse", random_base_prob=1.0, random_segment=3))
    plan = make_plan(cfg)
    rid = plan.clip_names.index(RANDOM_CLIP)
    expected = random_poses(plan.character, 24, seed=1, fps=5.0, mode="sparse", base_clips=["stretch"],
                            base_clip_prob=1.0, segment=3)
    np.testing.assert_allclose(plan.pose[plan.clip_id == rid], plan.character.pose(expected).features, atol=1e-6)
    assert plan.splits == {"train": ["stretch", RANDOM_CLIP], "heldout": ["wave"]}
    uniform = make_plan(config_from_dict(_cfg()))  # default stays the original sampler
    np.testing.assert_allclose(uniform.pose[uniform.clip_id == rid],
                               plan.character.pose(random_poses(plan.character, 24, seed=1)).features, atol=1e-6)
    with pytest.raises(PrtError, match="random_mode"):
        config_from_dict(_cfg(random_mode="grid"))
    with pytest.raises(PrtError, match="random_segment"):
        config_from_dict(_cfg(random_segment=0))


# --- no held-out frame ever feeds a training pose (issue 8, item 0) -------------------------------------------------

SIG_JOINT = 1  # a non-root joint whose local translation marks held-out frames (no clip or the bind pose moves it)
SIG = np.array([0.0, 0.0, 3.0])


def _signed_character(limits: bool, split: int | None = None) -> Character:
    """The small built-in humanoid (5 fps) whose held-out frames carry a signature: ``wave`` and, with ``split``,
    ``walk`` frames ``split:``. With ``limits=False`` it has no joint limits (the glTF/BVH path)."""
    c = builtin.make_character(0.05, fps=5.0)
    clips = dict(c.clips)
    for name, start in [("wave", 0)] + ([("walk", split)] if split is not None else []):
        local = clips[name].local.copy()
        local[start:, SIG_JOINT, :3, 3] += SIG
        clips[name] = Clip(name, clips[name].fps, local)
    return replace(c, clips=clips, joint_limits=c.joint_limits if limits else None)


def _signature_distance(character: Character, local: np.ndarray) -> np.ndarray:
    """``(F,)`` distance of each frame's signature-joint translation from the nearest clean one (bind pose)."""
    clean = character.bind_local[SIG_JOINT, :3, 3]
    return np.linalg.norm(local[:, SIG_JOINT, :3, 3] - clean, axis=-1)


LEAK_CASES = {
    "uniform-limits": dict(random_mode="uniform"),
    "uniform-no-limits": dict(random_mode="uniform", limits=False),
    "sparse-limits-bases": dict(random_mode="sparse", random_base_prob=1.0),
    "sparse-no-limits-bases": dict(random_mode="sparse", random_base_prob=1.0, limits=False),
    "sparse-limits-no-bases": dict(random_mode="sparse", random_base_prob=1.0, train_clips=[]),
    "sparse-no-limits-no-bases": dict(random_mode="sparse", random_base_prob=1.0, train_clips=[], limits=False),
    "sparse-segment": dict(random_mode="sparse", random_base_prob=0.7, random_segment=3),
    "sparse-segment-no-limits": dict(random_mode="sparse", random_base_prob=0.7, random_segment=3, limits=False),
    "cpca-limits": dict(random_mode="cpca"),
    "cpca-no-limits": dict(random_mode="cpca", limits=False),
    "cpca-few-clusters": dict(random_mode="cpca", random_cpca_clusters=2, random_cpca_components=3, limits=False),
}


@pytest.mark.parametrize("split", [False, True], ids=["clips", "within-clip"])
@pytest.mark.parametrize("case", list(LEAK_CASES))
def test_no_heldout_frame_feeds_a_random_pose(case: str, split: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every random pose of a plan derives from the bind pose or training frames only: held-out frames carry a
    translation signature that survives every sampler (copied bases / sources, slerp segments lerp translations)."""
    import prt_torch.rig.random_pose as rp

    opts = dict(LEAK_CASES[case])
    limits = bool(opts.pop("limits", True))
    character = _signed_character(limits, split=6 if split else None)
    train = opts.pop("train_clips", ["stretch", "squat"])
    heldout = ["wave"]
    if split:
        train = train + [{"clip": "walk", "frames": ":6"}]
        heldout = [{"clip": "walk", "frames": "6:"}] + heldout
    made = []

    def spy(*args: object, **kwargs: object) -> Clip:
        made.append(rp_random_poses(*args, **kwargs))
        return made[-1]

    rp_random_poses = rp.random_poses
    monkeypatch.setattr(rp, "random_poses", spy)
    cfg = config_from_dict(_cfg(train_clips=train, heldout_clips=heldout, random_poses=90, **opts))
    plan = make_plan(cfg, character=character)
    assert len(made) == 1 and made[0].num_frames == 90
    # the signature is there to find: every held-out frame carries it, no training frame does
    assert np.all(_signature_distance(character, character.clips["wave"].local) > 2.9)
    for name in plan.splits["train"]:
        if name != RANDOM_CLIP:
            src = name.split("[")[0]
            idx = plan.frame_index[plan.clip_id == plan.clip_names.index(name)]
            assert np.all(_signature_distance(character, character.clips[src].local[idx]) < 1e-12)
    # no random pose derives from a held-out frame (interpolated frames towards one would be >= 1.0 off)
    d = _signature_distance(character, made[0].local)
    assert d.max() < 1e-9, f"{np.count_nonzero(d > 1e-9)} of 90 random poses derive from held-out frames"
    # sources used: the training range of walk
    if case in ("uniform-no-limits", "sparse-no-limits-bases", "cpca-no-limits") and split:
        walk = character.clips["walk"].local[:6, 2:, :3, 3]
        assert np.any(np.all(np.isclose(made[0].local[:, None, 2:, :3, 3], walk[None]), axis=(-1, -2)))


def test_uniform_without_limits_needs_training_clips(humanoid: Character) -> None:
    c = replace(humanoid, joint_limits=None)
    with pytest.raises(PrtError, match="no joint limits and no training clip"):
        random_poses(c, 4)  # never falls back to the character's (possibly held-out) clips
    with pytest.raises(PrtError, match="no joint limits and no training clip"):
        make_plan(config_from_dict(_cfg(train_clips=[], random_poses=4)), character=c)
    # with training clips: only their frames are sources
    clip = random_poses(c, 40, seed=0, perturb_deg=0.0, base_clips=["squat"])
    squat = c.clips["squat"].local[:, 1:]
    assert all(np.any(np.all(np.isclose(squat, f[None, 1:], atol=1e-12), axis=(1, 2, 3))) for f in clip.local)


def test_random_perturb_deg_is_passed_through() -> None:
    c = replace(builtin.make_character(0.05, fps=5.0), joint_limits=None)
    for deg in (0.0, 7.0):
        plan = make_plan(config_from_dict(_cfg(random_perturb_deg=deg)), character=c)
        expected = random_poses(c, 24, seed=1, perturb_deg=deg, fps=5.0, base_clips=["stretch"])
        rid = plan.clip_names.index(RANDOM_CLIP)
        np.testing.assert_allclose(plan.pose[plan.clip_id == rid], c.pose(expected).features, atol=1e-6)
    for bad in (-1.0, 181.0):
        with pytest.raises(PrtError, match="random_perturb_deg"):
            config_from_dict(_cfg(random_perturb_deg=bad))
