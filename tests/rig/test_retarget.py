"""Retargeting (prt_torch.rig.retarget) against an independent BVH forward kinematics written here with scipy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rig.retarget import (
    MotionSource,
    compose_angles,
    limit_angles_of,
    load_motion,
    retarget,
    retarget_file,
)
from prt_torch.rig.skeleton import forward_kinematics

# a small CMU-3dsMax-named skeleton: (name, parent, offset (y up), channel order); Chest is unmapped (folded)
_SKEL: list[tuple[str, str | None, tuple[float, float, float], str]] = [
    ("Hips", None, (0.0, 0.0, 0.0), "ZYX"),
    ("lowerback", "Hips", (0.0, 0.5, 0.0), "ZYX"),
    ("Chest", "lowerback", (0.0, 2.0, 0.2), "ZYX"),
    ("Chest2", "Chest", (0.0, 2.0, -0.1), "ZYX"),
    ("lowerneck", "Chest2", (0.0, 1.0, 0.0), "ZYX"),
    ("Head", "lowerneck", (0.0, 1.5, 0.3), "ZYX"),
]
for _s, _x in (("Left", 1.0), ("Right", -1.0)):  # depth-first order, as in the file
    _SKEL += [
        (f"{_s}Collar", "Chest2", (0.3 * _x, 0.8, 0.0), "ZYX"),
        (f"{_s}Shoulder", f"{_s}Collar", (2.0 * _x, 0.3, 0.0), "ZXY"),
        (f"{_s}Elbow", f"{_s}Shoulder", (0.0, -4.5, 0.0), "ZXY"),
        (f"{_s}Wrist", f"{_s}Elbow", (0.0, -3.5, 0.0), "ZXY"),
    ]
for _s, _x in (("Left", 1.0), ("Right", -1.0)):
    _SKEL += [
        (f"{_s}Hip", "Hips", (1.5 * _x, -1.5, 0.0), "ZYX"),
        (f"{_s}Knee", f"{_s}Hip", (0.5 * _x, -6.5, 0.0), "ZYX"),
        (f"{_s}Ankle", f"{_s}Knee", (0.3 * _x, -6.5, 0.0), "ZYX"),
        (f"{_s}Toe", f"{_s}Ankle", (0.0, -0.5, 2.0), "ZYX"),
    ]
NAMES = [s[0] for s in _SKEL]
ROLE = {"Hips": "pelvis", "lowerback": "spine", "Chest2": "chest", "lowerneck": "neck", "Head": "head"}
for _s, _r in (("Left", "l"), ("Right", "r")):
    ROLE.update({f"{_s}Collar": f"clavicle_{_r}", f"{_s}Shoulder": f"shoulder_{_r}", f"{_s}Elbow": f"elbow_{_r}",
                 f"{_s}Wrist": f"wrist_{_r}", f"{_s}Hip": f"hip_{_r}", f"{_s}Knee": f"knee_{_r}",
                 f"{_s}Ankle": f"ankle_{_r}", f"{_s}Toe": f"toe_{_r}"})
#: (source joint, source child) bones of non-branching mapped joints, whose directions retargeting copies
BONES = [("lowerback", "Chest2"), ("lowerneck", "Head")] + [
    (f"{s}{a}", f"{s}{b}") for s in ("Left", "Right") for a, b in
    (("Collar", "Shoulder"), ("Shoulder", "Elbow"), ("Elbow", "Wrist"), ("Hip", "Knee"), ("Knee", "Ankle"),
     ("Ankle", "Toe"))]
FPS_SRC = 120.0
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # y up -> z up


def _motion(n: int = 48, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Root positions ``(n, 3)`` (y up) and Euler degrees ``(n, J, 3)`` (unwrapped: beyond +-180)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FPS_SRC
    root = np.stack([3.0 * np.sin(2 * t), 15.0 + np.sin(9 * t), 4.0 * t], axis=1)
    k = rng.normal(size=(len(NAMES), 3, 2))
    ang = 35.0 * np.sin(t[:, None, None] * 6 * k[..., 0] + k[..., 1]) + 10.0 * k[None, ..., 0]
    ang[:, 0, 1] += 360.0 + 40.0 * t  # root yaw unwrapped past 360 degrees
    return np.round(root, 6), np.round(ang, 6)  # as written to the file


def _write_bvh(path: Path, root: np.ndarray, ang: np.ndarray) -> None:
    lines = ["HIERARCHY"]
    order: list[str] = []
    for i, (name, parent, off, axes) in enumerate(_SKEL):
        # close blocks down to this joint's parent
        while order and order[-1] != parent:
            order.pop()
            lines.append("  " * len(order) + "}")
        d = len(order)
        kw = "ROOT" if parent is None else "JOINT"
        ch = " ".join(f"{a}rotation" for a in axes)
        lines += ["  " * d + f"{kw} {name}", "  " * d + "{",
                  "  " * (d + 1) + "OFFSET {:.6f} {:.6f} {:.6f}".format(*off),
                  "  " * (d + 1) + (f"CHANNELS 6 Xposition Yposition Zposition {ch}" if i == 0 else f"CHANNELS 3 {ch}")]
        if not any(p == name for _, p, _, _ in _SKEL):
            lines += ["  " * (d + 1) + "End Site", "  " * (d + 1) + "{", "  " * (d + 2) + "OFFSET 0 -1 0",
                      "  " * (d + 1) + "}"]
        order.append(name)
    while order:
        order.pop()
        lines.append("  " * len(order) + "}")
    lines += ["MOTION", f"Frames: {len(root)}", f"Frame Time: {1.0 / FPS_SRC:.8f}"]
    for f in range(len(root)):
        lines.append(" ".join(f"{v:.6f}" for v in np.concatenate([root[f], ang[f].ravel()])))
    path.write_text("\n".join(lines) + "\n")


def _fk(root: np.ndarray, ang: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent FK: world positions ``(F, J, 3)`` and rotations ``(F, J, 3, 3)`` in the z-up world."""
    n = len(root)
    idx = {name: i for i, (name, _, _, _) in enumerate(_SKEL)}
    pos = np.zeros((n, len(_SKEL), 3))
    rot = np.zeros((n, len(_SKEL), 3, 3))
    for i, (_, parent, off, axes) in enumerate(_SKEL):
        r = Rotation.from_euler(axes, ang[:, i], degrees=True).as_matrix()
        if parent is None:
            pos[:, i] = root
            rot[:, i] = r
        else:
            p = idx[parent]
            pos[:, i] = pos[:, p] + np.einsum("fij,j->fi", rot[:, p], np.array(off))
            rot[:, i] = rot[:, p] @ r
    return pos @ C.T, C @ rot


def _target(scale: float = 0.05, t_pose_arms: bool = False, limits: np.ndarray | None = None) -> Character:
    """A synthetic target with the built-in names at the source's mapped rest joint positions (scaled); with
    ``t_pose_arms`` the source's arms-down rest arms are raised to a T-pose (rest directions differ)."""
    p0, _ = _fk(np.zeros((1, 3)), np.zeros((1, len(_SKEL), 3)))
    p0 = p0[0] * scale
    mapped = [n for n in NAMES if n in ROLE]
    pos = {n: p0[NAMES.index(n)].copy() for n in mapped}
    if t_pose_arms:
        for s, x in (("Left", 1.0), ("Right", -1.0)):
            sh = pos[f"{s}Shoulder"]
            for j, d in ((f"{s}Elbow", 4.5), (f"{s}Wrist", 8.0)):
                pos[j] = sh + np.array([x * d * scale, 0.0, 0.0])
    parent_of = {n: p for n, p, _, _ in _SKEL}
    tparent = []
    for n in mapped:
        p = parent_of[n]
        while p is not None and p not in ROLE:
            p = parent_of[p]
        tparent.append(-1 if p is None else mapped.index(p))
    j = len(mapped)
    world = np.tile(np.eye(4), (j, 1, 1))
    world[:, :3, 3] = [pos[n] for n in mapped]
    local = world.copy()
    for i, p in enumerate(tparent):
        if p >= 0:
            local[i] = np.linalg.inv(world[p]) @ world[i]
    verts = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    return Character("synthetic", [ROLE[n] for n in mapped], np.array(tparent), local, np.linalg.inv(world), verts,
                     np.tile([0.0, 0.0, 1.0], (3, 1)), np.array([[0, 1, 2]]), np.zeros((3, 1), np.int64),
                     np.ones((3, 1), np.float32), {}, limits)


@pytest.fixture(scope="module")
def bvh(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    root, ang = _motion()
    path = tmp_path_factory.mktemp("bvh") / "synthetic.bvh"
    _write_bvh(path, root, ang)
    return path, root, ang


def _dirs(p: np.ndarray, a: int, b: int) -> np.ndarray:
    d = p[:, b] - p[:, a]
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("t_pose", [False, True])
def test_bone_directions_and_root_match_independent_fk(bvh: tuple[Path, np.ndarray, np.ndarray],
                                                         t_pose: bool) -> None:
    path, root, ang = bvh
    target = _target(t_pose_arms=t_pose)
    clip, rep = retarget(load_motion(path), target)  # the file's rate: frame-by-frame comparison
    assert rep.source_family == "cmu-3dsmax" and rep.target_family == "builtin" and not rep.skipped_first
    assert rep.unmapped_source == ["Chest"] and rep.unmapped_target == [] and rep.frames == len(root)
    ps, _ = _fk(root, ang)
    pt = forward_kinematics(target.parents, clip.local)[..., :3, 3]
    tn = target.joint_names
    for a, b in BONES:
        got = _dirs(pt, tn.index(ROLE[a]), tn.index(ROLE[b]))
        want = _dirs(ps, NAMES.index(a), NAMES.index(b))
        np.testing.assert_allclose(got, want, atol=1e-9, err_msg=f"{a}->{b}")
    # root: leg-length ratio (0.05 here: the target is the source scaled), horizontal from the rest spot
    assert rep.scale == pytest.approx(0.05, rel=1e-9)
    p_src = ps[:, 0]
    rest_xy = np.linalg.inv(target.inverse_bind[0])[:2, 3]
    np.testing.assert_allclose(pt[:, 0, :2], rest_xy + 0.05 * (p_src[:, :2] - p_src[0, :2]), atol=1e-9)
    # height: the source's standing ankle level (median of the lower ankle) lands on the target's rest ankle
    # height above its floor (the lowest rest vertex, z = 0 here)
    a_src = np.median(np.minimum(ps[:, NAMES.index("LeftAnkle"), 2], ps[:, NAMES.index("RightAnkle"), 2]))
    rest_world = np.linalg.inv(target.inverse_bind)
    h_ankle = (rest_world[tn.index("ankle_l"), 2, 3] + rest_world[tn.index("ankle_r"), 2, 3]) / 2
    np.testing.assert_allclose(pt[:, 0, 2], h_ankle + 0.05 * (p_src[:, 2] - a_src), atol=1e-9)


def test_resampling_and_unwrapped_angles(bvh: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, root, ang = bvh
    target = _target()
    clip, rep = retarget_file(path, target, fps=30.0)
    fps_file = 1.0 / float(f"{1.0 / FPS_SRC:.8f}")  # "Frame Time: 0.00833333": not exactly 120 fps
    assert rep.fps == 30.0 and clip.num_frames == int(np.floor((len(root) - 1) / fps_file * 30 + 1e-9)) + 1
    ps, _ = _fk(root[::4], ang[::4])  # 120 -> 30 fps: every 4th source frame (to the frame time's rounding)
    pt = forward_kinematics(target.parents, clip.local)[..., :3, 3]
    a, b = NAMES.index("LeftShoulder"), NAMES.index("LeftElbow")
    np.testing.assert_allclose(_dirs(pt, target.joint_names.index("shoulder_l"), target.joint_names.index("elbow_l")),
                               _dirs(ps, a, b)[:clip.num_frames], atol=1e-4)


def test_joint_limit_clamping_counts(bvh: tuple[Path, np.ndarray, np.ndarray]) -> None:
    path, _, _ = bvh
    free = _target()
    clip_free, rep_free = retarget(load_motion(path), free)
    assert rep_free.frames_clamped == 0
    lim = np.tile(np.array([[-4.0, 4.0]]), (free.num_joints, 3, 1))
    w = free.joint_names.index("wrist_l")
    lim[w] = [[-0.2, 0.3], [-4.0, 4.0], [-0.1, 0.1]]  # a leaf joint: clamping it changes no other joint
    limited = _target(limits=lim)
    clip, rep = retarget(load_motion(path), limited, tol_deg=0.5)
    rb = free.bind_local[w, :3, :3]
    a_free = limit_angles_of(rb.T @ clip_free.local[:, w, :3, :3])
    excess = np.max(np.abs(a_free - np.clip(a_free, lim[w, :, 0], lim[w, :, 1])), axis=-1)
    expected = int(np.sum(excess > np.radians(0.5)))
    assert expected > 0
    assert rep.frames_clamped == expected and rep.clamped_frames == {"wrist_l": expected}
    assert rep.max_excess_deg["wrist_l"] == pytest.approx(np.degrees(excess.max()))
    a = limit_angles_of(rb.T @ clip.local[:, w, :3, :3])
    assert np.all(a >= lim[w, :, 0] - 1e-9) and np.all(a <= lim[w, :, 1] + 1e-9)
    others = [j for j in range(free.num_joints) if j != w]
    np.testing.assert_allclose(clip.local[:, others], clip_free.local[:, others], atol=1e-12)


def test_limit_angle_convention_matches_random_pose() -> None:
    from prt_torch.rig.random_pose import compose_limit_angles

    ang = np.random.default_rng(1).uniform(-1.2, 1.2, size=(50, 3))
    np.testing.assert_allclose(compose_angles(ang), compose_limit_angles(ang), atol=1e-12)
    np.testing.assert_allclose(limit_angles_of(compose_angles(ang)), ang, atol=1e-9)


def test_identity_retarget_on_builtin() -> None:
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=10.0)
    clip, rep = retarget(MotionSource.from_character(ch, "walk"), ch)
    w0, w1 = ch.pose("walk").world, ch.pose(clip).world
    np.testing.assert_allclose(w1[..., :3, :3], w0[..., :3, :3], atol=1e-9)  # every joint, limits respected
    assert rep.scale == pytest.approx(1.0)


@pytest.mark.parametrize("name,family,skipped", [("94_01", "cmu-3dsmax", False), ("05_20", "cmu-mobu", True)])
def test_cmu_families_on_builtin(shared_data: Path, name: str, family: str, skipped: bool) -> None:
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=30.0)
    src = load_motion(shared_data / "motion" / f"{name}.bvh")
    clip, rep = retarget(src, ch, fps=30.0, name=name)
    assert rep.source_family == family and rep.skipped_first == skipped and len(rep.joint_map) == 21
    n_src = src.clip.num_frames - skipped
    assert clip.num_frames == int(np.floor((n_src - 1) / src.clip.fps * 30 + 1e-9)) + 1
    world = forward_kinematics(ch.parents, clip.local)
    z = world[..., 2, 3]
    names = ch.joint_names
    assert 0.5 < np.median(z[:, names.index("pelvis")]) < 1.2  # standing-ish hips
    toes = z[:, [names.index("toe_l"), names.index("toe_r"), names.index("ankle_l"), names.index("ankle_r")]]
    assert np.percentile(toes.min(axis=1), 50) < 0.15 and toes.min() > -0.2  # feet near the floor
    head = z[:, names.index("head")] - z[:, names.index("pelvis")]
    assert np.median(head) > 0.4  # upright
    wrists = z[:, [names.index("wrist_l"), names.index("wrist_r")]].max(axis=1)
    assert np.mean(wrists > z[:, names.index("head")]) > 0.05  # arms above the head in these dances
    if skipped:  # the artificial T-pose frame is gone: the first frame's arms are not horizontal
        d = world[0, names.index("elbow_l"), :3, 3] - world[0, names.index("shoulder_l"), :3, 3]
        assert abs(d[2]) / np.linalg.norm(d) > 0.3


def test_gltf_humanoid_clip_on_builtin(shared_data: Path) -> None:
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=30.0)
    clip, rep = retarget_file(shared_data / "characters" / "RiggedFigure.glb", ch)
    assert rep.source_family == "cesium" and len(rep.joint_map) == 19 and clip.num_frames == 38
    assert np.all(np.isfinite(clip.local))


def _one_line(e: pytest.ExceptionInfo[PrtError]) -> str:
    msg = str(e.value)
    assert "\n" not in msg
    return msg


def test_bad_motion_files(tmp_path: Path, bvh: tuple[Path, np.ndarray, np.ndarray]) -> None:
    good = bvh[0].read_text()
    target = _target()
    rows = good.split("Frame Time:")[1].splitlines()[1:]
    cases = {
        "truncated.bvh": good[: len(good) // 3],
        "nan.bvh": good.replace(rows[3], rows[3].replace(rows[3].split()[5], "nan", 1)),
        "channels.bvh": good.replace(rows[2], " ".join(rows[2].split()[:-2])),
    }
    for fname, text in cases.items():
        p = tmp_path / fname
        p.write_text(text)
        with pytest.raises(PrtError) as e:
            retarget_file(p, target)
        _one_line(e)
    with pytest.raises(PrtError) as e:
        retarget_file(tmp_path / "missing.bvh", target)
    assert "not found" in _one_line(e)
    with pytest.raises(PrtError) as e:
        retarget_file(bvh[0], target, joint_map={"NoSuchJoint": "head"})
    assert "NoSuchJoint" in _one_line(e)
    with pytest.raises(PrtError) as e:
        retarget_file(bvh[0], target, joint_map={"Head": "no_such_target"})
    assert "no_such_target" in _one_line(e)
    with pytest.raises(PrtError) as e:  # unmapping a required joint
        retarget_file(bvh[0], target, joint_map={"LeftKnee": None})
    assert "knee_l" in _one_line(e)


def test_quadruped_is_refused(shared_data: Path, bvh: tuple[Path, np.ndarray, np.ndarray]) -> None:
    from prt_torch.rig.gltf import load_gltf

    fox_path = shared_data / "characters" / "Fox.glb"
    with pytest.raises(PrtError) as e:  # Fox's clip as the motion
        retarget_file(fox_path, _target())
    assert "humanoid" in _one_line(e)
    fox = load_gltf(fox_path)
    with pytest.raises(PrtError) as e:  # Fox as the target
        retarget_file(bvh[0], fox)
    assert "humanoid" in _one_line(e)
    forced = {"Hips": "b_Hip_01", "lowerback": "b_Spine01_02", "Head": "b_Head_05", "LeftShoulder":
              "b_LeftUpperArm_09", "LeftElbow": "b_LeftForeArm_010", "RightShoulder": "b_RightUpperArm_06",
              "RightElbow": "b_RightForeArm_07", "LeftHip": "b_LeftLeg01_015", "LeftKnee": "b_LeftLeg02_016",
              "RightHip": "b_RightLeg01_019", "RightKnee": "b_RightLeg02_020"}
    with pytest.raises(PrtError) as e:  # every required joint forced: the rest pose is not upright
        retarget_file(bvh[0], fox, joint_map=forced)
    assert "upright" in _one_line(e)
