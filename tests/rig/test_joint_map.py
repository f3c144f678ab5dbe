"""The structural humanoid joint map (prt_torch.rig.joint_map) and retargeting every shared skeleton with it.

References are independent of the code under test: the built-in humanoid's joint names are its roles; the
shared files' anatomy (SOURCES.md: which CMU release each BVH is, which has a converter's reference frame,
its units) and the files' own left/right names; renamings must give the same joints by identity.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.rig.joint_map import find_roles, name_side
from prt_torch.rig.retarget import ROLES, MotionSource, load_motion, retarget
from prt_torch.rig.skeleton import forward_kinematics

DAZ = ("02_03", "02_04", "03_01", "09_01", "09_06", "13_11", "13_13", "13_39", "13_41", "13_42")
MOBU = ("01_01", "01_03", "05_20")
MAX3DS = ("102_01", "131_01", "94_01")
ASF = ("16_01",)
ALL_BVH = DAZ + MOBU + MAX3DS + ASF


def _rest(src: MotionSource) -> np.ndarray:
    return forward_kinematics(src.parents, src.rest_local[None])[0][:, :3, 3]


def _renamed(src: MotionSource, how: str, seed: int) -> tuple[MotionSource, np.ndarray]:
    """A copy of ``src`` with joint names rewritten by ``how`` and joints in a shuffled (still parent-first)
    order, and ``old (J,)``: the original index of each new joint."""
    rng = np.random.default_rng(seed)
    kids: list[list[int]] = [[] for _ in src.joint_names]
    roots = []
    for j, p in enumerate(src.parents):
        (kids[int(p)] if p >= 0 else roots).append(j)
    order: list[int] = []
    frontier = list(roots)
    while frontier:  # a random topological order: any joint whose parent is placed may come next
        j = frontier.pop(int(rng.integers(len(frontier))))
        order.append(j)
        frontier += kids[j]
    old = np.array(order)
    new_of = {o: n for n, o in enumerate(order)}
    parents = np.array([-1 if src.parents[o] < 0 else new_of[int(src.parents[o])] for o in order])

    def rename(name: str, i: int) -> str:
        if how == "prefix":
            return f"Skeleton_{name}"
        if how == "suffix":
            return f"{name}__{i + 3}_"
        if how == "case":
            return name.upper() if i % 2 else name.lower()
        if how == "separators":
            return name.replace("_", ".").replace(" ", "-") + f".{i:03d}"
        return f"joint{i}"  # opaque names: structure only

    names = [rename(src.joint_names[o], n) for n, o in enumerate(order)]
    clip = type(src.clip)(src.clip.name, src.clip.fps, src.clip.local[:, old])
    return MotionSource(src.name, names, parents, src.rest_local[old], clip, src.kind), old


def _roles(src: MotionSource) -> dict[str, int]:
    return find_roles(src.joint_names, src.parents, _rest(src), src.name).roles


def _check_renamings(src: MotionSource) -> dict[str, int]:
    base = _roles(src)
    for k, how in enumerate(("prefix", "suffix", "case", "separators", "opaque")):
        ren, old = _renamed(src, how, seed=k)
        got = {r: int(old[j]) for r, j in _roles(ren).items()}
        assert got == base, how
    return base


def test_builtin_roles_are_its_joint_names_under_renaming() -> None:
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=10.0)
    src = MotionSource.from_character(ch, "walk")
    roles = _check_renamings(src)
    assert {r: ch.joint_names[j] for r, j in roles.items()} == {r: r for r in ROLES}


def test_name_side_tie_breaker() -> None:
    assert [name_side(n) for n in ("LeftHand", "lThigh", "arm_joint_L_3", "thigh.l", "mixamorig:RightArm",
                                   "rShin", "Hips", "leftEye", "Spine")] == [1, 1, 1, 1, -1, -1, 0, 1, 0]


def _file_side(name: str) -> int:
    """The left/right that the file's own joint name says (an independent reference for the structural map):
    also CMU ASF names (``lfemur``, ``rtibia``)."""
    return name_side(name) or {"l": 1, "r": -1}.get(name[:1], 0)


@pytest.mark.parametrize("name", ALL_BVH)
def test_every_cmu_clip_maps_and_retargets(shared_data: Path, name: str) -> None:
    from prt_torch.rig.builtin import make_character

    src = load_motion(shared_data / "motion" / f"{name}.bvh")
    roles = _check_renamings(src)
    for r, j in roles.items():  # left/right from geometry agrees with the file's names
        side = {"_l": 1, "_r": -1}.get(r[-2:], 0)
        assert side == 0 or _file_side(src.joint_names[j]) == side, (r, src.joint_names[j])
    assert "head" in src.joint_names[roles["head"]].lower()
    assert len(roles) == (19 if name in DAZ else 21)  # the Daz release has no toe joints
    ch = make_character(0.05, fps=30.0)
    clip, rep = retarget(src, ch, fps=30.0, name=name)
    # SOURCES.md: MotionBuilder and Daz releases start with a converter's reference pose; the others do not
    assert rep.skipped_first == (name in DAZ + MOBU)
    assert any("reference pose" in w for w in rep.warnings) == rep.skipped_first
    assert rep.source_units == ("centimetres" if name in DAZ else "CMU units (0.0564 m)")
    # SOURCES.md: every clip is 120 fps data; 16_01's header says 30 fps (gravity in its jumps says 120)
    assert any("gravity" in w for w in rep.warnings) == (name == "16_01")
    n_src = src.clip.num_frames - rep.skipped_first
    assert abs(clip.num_frames - (int(np.floor((n_src - 1) / 120.0 * 30.0)) + 1)) <= 1
    assert all(w.startswith("warning: ") and "\n" not in w for w in rep.warnings)
    _plausible(ch, clip.local, src, roles)


def _hands_side(w: np.ndarray, hip_l: int, hip_r: int, wrist_l: int, wrist_r: int) -> np.ndarray:
    """``(F,)``: how far the left hand is left of the right one, in the hips' frame (left = the left hip's side);
    ``w (F, J, 3)`` world positions."""
    left = w[:, hip_l] - w[:, hip_r]
    left[:, 2] = 0.0
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    return np.einsum("fi,fi->f", w[:, wrist_l] - w[:, wrist_r], left)


def _hands_left(w: np.ndarray, hip_l: int, hip_r: int, wrist_l: int, wrist_r: int, apart: float) -> float:
    """Fraction of frames (of those with the hands more than ``apart`` apart sideways) with the left hand on the
    left (:func:`_hands_side`)."""
    hands = _hands_side(w, hip_l, hip_r, wrist_l, wrist_r)
    clear = np.abs(hands) > apart
    return float(np.mean(hands[clear] > 0)) if clear.any() else 1.0


def _plausible(ch, local: np.ndarray, src: MotionSource, roles: dict[str, int]) -> None:  # noqa: ANN001
    assert np.all(np.isfinite(local))
    w = forward_kinematics(ch.parents, local)[..., :3, 3]
    i = {n: k for k, n in enumerate(ch.joint_names)}
    floor = float(ch.rest_vertices[:, 2].min())
    feet = w[:, [i["toe_l"], i["toe_r"], i["ankle_l"], i["ankle_r"]], 2].min(axis=1) - floor
    assert -0.06 < np.median(feet) < 0.15 and feet.min() > -0.3  # feet near the floor over the clip
    assert np.median(w[:, i["head"], 2] - w[:, i["pelvis"], 2]) > 0.4  # upright
    # the left hip on the character's left in the rest-facing frame: the built-in faces -y with its left (the
    # ``_l`` joints) at +x; the frame turns with the pelvis's heading
    wr = forward_kinematics(ch.parents, local)[:, i["pelvis"], :3, :3]
    r0 = np.linalg.inv(ch.inverse_bind[i["pelvis"]])[:3, :3]
    left = wr @ np.linalg.solve(r0, [1.0, 0.0, 0.0])
    hips = np.einsum("fi,fi->f", w[:, i["hip_l"]] - w[:, i["hip_r"]], left)
    assert np.mean(hips > 0) > 0.9
    # the left hand on the left as often as in the source (whose sides its own names give, checked above)
    ws = forward_kinematics(src.parents, src.clip.local)[..., :3, 3]
    height_s = float(np.ptp(_rest(src)[:, 2]))
    height_t = float(np.ptp(np.linalg.inv(ch.inverse_bind)[:, 2, 3]))
    if len(ws) == len(w):  # same frames (a glTF clip at its own rate): frame by frame
        sgn_t = _hands_side(w, i["hip_l"], i["hip_r"], i["wrist_l"], i["wrist_r"]) / height_t
        sgn_s = _hands_side(ws, roles["hip_l"], roles["hip_r"], roles["wrist_l"], roles["wrist_r"]) / height_s
        clear = np.abs(sgn_s) > 0.1
        assert np.mean(np.sign(sgn_t[clear]) == np.sign(sgn_s[clear])) > 0.9
    else:  # resampled, reference frame dropped: as often
        got = _hands_left(w, i["hip_l"], i["hip_r"], i["wrist_l"], i["wrist_r"], 0.1 * height_t)
        want = _hands_left(ws, roles["hip_l"], roles["hip_r"], roles["wrist_l"], roles["wrist_r"], 0.1 * height_s)
        assert abs(got - want) < 0.15, (got, want)


@pytest.mark.parametrize("fname,expected", [
    ("RiggedFigure.glb", {"pelvis": "torso_joint_1", "head": "neck_joint_2", "shoulder_l": "arm_joint_L_1",
                          "wrist_r": "arm_joint_R_3", "knee_l": "leg_joint_L_2", "toe_r": "leg_joint_R_5"}),
    ("mannequiny-0.3.0.glb", {"pelvis": "pelvis", "head": "head", "clavicle_l": "clavicle.l",
                              "elbow_r": "lowerarm.r", "wrist_l": "hand.l", "hip_r": "thigh.r", "toe_l": "ball.l"}),
])
def test_gltf_humanoids_map_and_retarget(shared_data: Path, fname: str, expected: dict[str, str]) -> None:
    from prt_torch.rig.builtin import make_character
    from prt_torch.rig.gltf import load_gltf

    character = load_gltf(shared_data / "characters" / fname, fps=30.0)
    ch = make_character(0.05, fps=30.0)
    for clip_name in character.clips:
        src = MotionSource.from_character(character, clip_name, "gltf")
        roles = _check_renamings(src)
        assert {r: src.joint_names[roles[r]] for r in expected} == expected
        for r, j in roles.items():  # left/right from geometry agrees with the file's names
            side = {"_l": 1, "_r": -1}.get(r[-2:], 0)
            assert side == 0 or _file_side(src.joint_names[j]) == side, (r, src.joint_names[j])
        clip, rep = retarget(src, ch, fps=30.0)
        assert rep.source_units == "metres" and not rep.skipped_first
        _plausible(ch, clip.local, src, roles)
    # the glTF humanoid as the target of a built-in clip: maps every required role
    walk = MotionSource.from_character(ch, "walk")
    clip, rep = retarget(walk, character)
    assert np.all(np.isfinite(clip.local)) and len(rep.joint_map) >= 15


def test_fox_is_refused_in_one_line(shared_data: Path) -> None:
    from prt_torch.rig.builtin import make_character

    fox = load_motion(shared_data / "characters" / "Fox.glb")
    with pytest.raises(PrtError) as e:
        find_roles(fox.joint_names, fox.parents, _rest(fox), fox.name)
    assert "4 limb chains reach the ground" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(PrtError) as e:
        retarget(fox, make_character(0.05))
    assert "humanoid" in str(e.value) and "4 limb chains" in str(e.value) and "\n" not in str(e.value)


def test_extra_joints_stay_unmapped() -> None:
    """The built-in skeleton plus a head-top end leaf, eyes, forearm and thigh twist leaves (siblings of the
    wrist / knee at mid-bone): the roles stay the built-in joints (an independent reference: its names)."""
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=10.0)
    names, parents = list(ch.joint_names), [int(p) for p in ch.parents]
    world = np.linalg.inv(ch.inverse_bind)
    pos = [w[:3, 3] for w in world]
    i = {n: k for k, n in enumerate(names)}

    def add(name: str, parent: int, p: np.ndarray) -> int:
        names.append(name)
        parents.append(parent)
        pos.append(np.asarray(p, float))
        return len(names) - 1

    head = pos[i["head"]]
    add("HeadTop_End", i["head"], head + [0.0, 0.0, 0.2])
    add("eye.L", i["head"], head + [0.03, -0.08, 0.05])
    add("eye.R", i["head"], head + [-0.03, -0.08, 0.05])
    add("thigh_twist_l", i["hip_l"], (pos[i["hip_l"]] + pos[i["knee_l"]]) / 2)
    add("forearm_twist_l", i["elbow_l"], (pos[i["elbow_l"]] + pos[i["wrist_l"]]) / 2)
    order = np.argsort([len(_ancestors(parents, j)) for j in range(len(names))], kind="stable")
    new_of = {int(o): n for n, o in enumerate(order)}
    par = np.array([-1 if parents[o] < 0 else new_of[parents[o]] for o in order])
    rest = np.array([pos[o] for o in order])
    roles = find_roles([names[o] for o in order], par, rest, "extended").roles
    assert {r: names[order[j]] for r, j in roles.items()} == {r: r for r in ROLES}


def _ancestors(parents: list[int], j: int) -> list[int]:
    out = []
    while parents[j] >= 0:
        j = parents[j]
        out.append(j)
    return out
