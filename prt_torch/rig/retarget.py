"""Retargeting: play a humanoid motion (a BVH file or a glTF clip) on another humanoid character.

numpy + scipy only (no torch: ``prt play --motion`` runs it on the player's path).

**Joint map.** Source and target joints are paired through humanoid *roles* (the built-in humanoid's
joint names: ``pelvis spine chest neck head``, ``clavicle shoulder elbow wrist`` and
``hip knee ankle toe`` per side ``_l``/``_r``), found on each skeleton from its topology and rest geometry
by :func:`prt_torch.rig.joint_map.find_roles` (two leg chains and a spine chain off the pelvis, left/right
from the rest pose's lateral axis and facing direction, arm chains off the upper spine, the head at the top;
names only break ties), so exporters' naming habits (prefixes, numbered suffixes, case, joint order) do not
matter. Fingers, eyes, twist and extra joints stay unmapped (they follow their parent). For example:

=========== ============ ============ ============= =========== ============= ============
role        cmu-3dsmax   cmu-mobu     mixamo        builtin     cesium        cmu-daz
=========== ============ ============ ============= =========== ============= ============
pelvis      Hips         Hips         Hips          pelvis      torso_joint_1 hip
spine       lowerback    LowerBack    Spine         spine       torso_joint_2 abdomen
chest       Chest2       Spine1       Spine2        chest       torso_joint_3 chest
neck        lowerneck    Neck         Neck          neck        neck_joint_1  neck
head        Head         Head         Head          head        neck_joint_2  head
clavicle_l  LeftCollar   LeftShoulder LeftShoulder  clavicle_l  (none)        lCollar
shoulder_l  LeftShoulder LeftArm      LeftArm       shoulder_l  arm_joint_L_1 lShldr
elbow_l     LeftElbow    LeftForeArm  LeftForeArm   elbow_l     arm_joint_L_2 lForeArm
wrist_l     LeftWrist    LeftHand     LeftHand      wrist_l     arm_joint_L_3 lHand
hip_l       LeftHip      LeftUpLeg    LeftUpLeg     hip_l       leg_joint_L_1 lThigh
knee_l      LeftKnee     LeftLeg      LeftLeg       knee_l      leg_joint_L_2 lShin
ankle_l     LeftAnkle    LeftFoot     LeftFoot      ankle_l     leg_joint_L_3 lFoot
toe_l       LeftToe      LeftToeBase  LeftToeBase   toe_l       leg_joint_L_5 (none)
=========== ============ ============ ============= =========== ============= ============

The naming family (these columns, :data:`FAMILIES`) is only a label in the report. ``joint_map {source:
target}`` overrides the structural pairs (a ``null`` target unmaps a source joint; unknown names are
errors); where a skeleton's structure is not humanoid the override alone pairs it. A pair is humanoid when
these roles map: pelvis, spine or chest, head, both shoulders (upper arms), elbows (forearms), hips
(thighs) and knees (shins), and each rest pose has the head above the pelvis (within 50 degrees of
vertical) and the knees below the hips; otherwise (Fox: four limb chains reach the ground) one-line error.

**Detected, not assumed.** *Units*: the source's rest height (joint z extent) against the target's gives
its length unit (``metres``, ``centimetres``, ``millimetres``, ``inches`` or CMU's ``0.0564 m``); root
motion is scaled by the leg-length ratio either way, and a unit other than the target's is a ``warning:``.
*Reference-pose frame*: a converter's added first frame (CMU MotionBuilder-friendly T-pose, Daz-friendly
reference pose) is detected by :func:`reference_frame`: frame 0 is the zero-channel rest pose (median
joint within 0.5 degrees of rest, the root's rotation too) and jumps to frame 1 by more than
``max(10 degrees, 4 x`` the clip's 90th-percentile frame-to-frame change), and is dropped with a ``warning:``.
*Frame time*: where the clip has flight phases, gravity gives the frame rate (:func:`flight_frame_rate`);
a header rate off by more than 1.5x (16_01.bvh says 30 fps for 120 fps data) is replaced, with a
``warning:``. All are in :class:`RetargetReport`.

**Rule.** World-space rotation deltas, after aligning rest bone directions. A mapped joint's rest bone
direction ``u`` is the unit vector from the joint to its *primary child* (the next mapped joint down the
chain; at a branch, the most upward one: pelvis -> spine, chest -> neck; zero-length bones are skipped).
With ``A`` the minimal rotation taking the source's ``u_s`` to the target's ``u_t`` (T-pose / A-pose /
arms-down differences) and ``D(t) = R_src_world(t) R_src_world_rest^-1``:

    ``R_tgt_world(t) = D(t) A^-1 R_tgt_world_rest``   so the target bone points along ``D(t) u_s``.

Unmapped source joints are folded into their mapped ancestors: world deltas already contain every
parent, and for a non-branching mapped joint ``D(t)`` is corrected by the minimal rotation taking
``D(t) u_s`` to the source's actual direction to the next mapped joint (e.g. CMU ``Chest`` between
``lowerback`` and ``Chest2``). So every non-branching mapped bone of the target points exactly along the
source's bone. Leaf joints (head, wrist, toe) use their parent's ``A``. Target world rotations are turned
back into local ones in hierarchy order; unmapped target joints keep their bind-pose local transform;
joint offsets stay the target's.

**Joint limits** (``Character.joint_limits``, angles of ``R_bind @ R_x @ R_z @ R_y``): each non-root mapped
joint's local rotation is clamped to its limits, in hierarchy order, and its children are re-solved
against the clamped parent (so they keep their world orientation). The report counts the frames where
any joint exceeded a limit by more than ``tol_deg``.

**Root motion.** ``k`` = target / source standing height: the pelvis's rest height above the mean of the
two ankles (where either skeleton maps no ankles: leg length, pelvis-to-hip height plus thigh and shin, mean
of both sides). The pelvis-mapped joint's world position is ``x, y = rest_xy + k (p_src(t) - p_src(0))_xy``
(the motion starts on the target's rest spot) and ``z = floor + h_ankle + k (p_src_z(t) - a_src)``:
``floor`` is the lowest rest vertex of the target, ``h_ankle`` its ankles' rest height above it, and
``a_src`` the source's standing ankle level, the median over the clip of the lower ankle's height;
so the source's own floor (``z = 0`` or not, a different ankle height) is not assumed (without ankles:
``z = floor + k p_src_z(t)``, the source floor at its world's ``z = 0``).

**Timing.** ``skip_first`` (default: detected, see above) drops frame 0, then the source is resampled to ``fps`` with
:meth:`Clip.resample` (slerp; Euler angles of any range are fine since they become matrices first).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.joint_map import HEAD_UP_MAX_DEG, find_roles
from prt_torch.rig.rotations import axis_angle_matrix
from prt_torch.rig.skeleton import forward_kinematics

SIDES = (("l", "Left", "L"), ("r", "Right", "R"))
_TORSO = ("pelvis", "spine", "chest", "neck", "head")
_LIMB = ("clavicle", "shoulder", "elbow", "wrist", "hip", "knee", "ankle", "toe")
#: humanoid roles (the built-in humanoid's joint names)
ROLES: tuple[str, ...] = _TORSO + tuple(f"{p}_{s}" for s, _, _ in SIDES for p in _LIMB)
#: roles that must map (``spine|chest``: either)
REQUIRED: tuple[str, ...] = ("pelvis", "spine|chest", "head", "shoulder_l", "elbow_l", "shoulder_r", "elbow_r",
                             "hip_l", "knee_l", "hip_r", "knee_r")
#: length units a source may be in: name -> metres
UNITS: dict[str, float] = {"metres": 1.0, "centimetres": 0.01, "millimetres": 0.001, "inches": 0.0254,
                           "CMU units (0.0564 m)": 0.056444}
#: standard frame rates a flight-phase estimate is rounded to
FRAME_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 100.0, 120.0, 240.0)
#: a reference-pose frame 0 jumps to frame 1 by more than this (degrees) ...
REFERENCE_JUMP_DEG = 10.0
#: ... and by more than this many times the clip's 90th-percentile frame-to-frame change
REFERENCE_JUMP_RATIO = 4.0


def _family(torso: tuple[tuple[str, ...], ...], limb: dict[str, str]) -> dict[str, tuple[str, ...]]:
    """role -> candidate joint names (first present wins); ``{S}`` = Left/Right, ``{s}`` = L/R."""
    out = {r: c for r, c in zip(_TORSO, torso, strict=True)}
    for s, side, short in SIDES:
        for part, pattern in limb.items():
            out[f"{part}_{s}"] = (pattern.format(S=side, s=short),)
    return out


_MOBU_LIMBS = {"clavicle": "{S}Shoulder", "shoulder": "{S}Arm", "elbow": "{S}ForeArm", "wrist": "{S}Hand",
               "hip": "{S}UpLeg", "knee": "{S}Leg", "ankle": "{S}Foot", "toe": "{S}ToeBase"}
#: naming families (detection order breaks ties)
FAMILIES: dict[str, dict[str, tuple[str, ...]]] = {
    "builtin": {r: (r,) for r in ROLES},
    "cmu-3dsmax": _family((("Hips",), ("lowerback",), ("Chest2",), ("lowerneck",), ("Head",)),
                          {"clavicle": "{S}Collar", "shoulder": "{S}Shoulder", "elbow": "{S}Elbow",
                           "wrist": "{S}Wrist", "hip": "{S}Hip", "knee": "{S}Knee", "ankle": "{S}Ankle",
                           "toe": "{S}Toe"}),
    "cmu-mobu": _family((("Hips",), ("LowerBack",), ("Spine1",), ("Neck",), ("Head",)), _MOBU_LIMBS),
    "mixamo": _family((("Hips",), ("Spine",), ("Spine2", "Spine1"), ("Neck",), ("Head",)), _MOBU_LIMBS),
    "cmu-daz": {k: v for k, v in _family((("hip",), ("abdomen",), ("chest",), ("neck",), ("head",)),
                                         {"clavicle": "{s}Collar", "shoulder": "{s}Shldr", "elbow": "{s}ForeArm",
                                          "wrist": "{s}Hand", "hip": "{s}Thigh", "knee": "{s}Shin",
                                          "ankle": "{s}Foot", "toe": ""}).items() if v != ("",)},
    "cesium": {k: v for k, v in _family(
        (("torso_joint_1",), ("torso_joint_2",), ("torso_joint_3",), ("neck_joint_1",), ("neck_joint_2",)),
        {"clavicle": "", "shoulder": "arm_joint_{s}_1", "elbow": "arm_joint_{s}_2", "wrist": "arm_joint_{s}_3",
         "hip": "leg_joint_{s}_1", "knee": "leg_joint_{s}_2", "ankle": "leg_joint_{s}_3",
         "toe": "leg_joint_{s}_5"}).items() if v != ("",)},
}


def _key(name: str) -> str:
    """Name comparison key: case-insensitive, without a ``prefix:`` (``mixamorig:Hips`` -> ``hips``)."""
    return name.rsplit(":", 1)[-1].lower()


def detect_roles(joint_names: list[str]) -> tuple[str, dict[str, int]]:
    """``(family, {role: joint index})`` of the naming family matching the most roles (``""`` if none): a label
    for the report only; the joint map itself is structural (:func:`prt_torch.rig.joint_map.find_roles`)."""
    index = {}
    for i, n in enumerate(joint_names):
        index.setdefault(_key(n), i)
    best: tuple[str, dict[str, int]] = ("", {})
    for fam, table in FAMILIES.items():
        roles: dict[str, int] = {}
        for role, cands in table.items():
            hit = next((index[_key(c)] for c in cands if _key(c) in index), None)
            if hit is not None and hit not in roles.values():
                roles[role] = hit
        if len(roles) > len(best[1]):
            best = (fam, roles)
    return best


@dataclass
class MotionSource:
    """A motion to retarget: a skeleton with its rest pose and one clip.

    ``joint_names`` (Js), ``parents (Js,)``, ``rest_local (Js, 4, 4)`` (the rest/bind pose; BVH: the
    zero-channel pose, roots in the z-up world), ``clip`` (``local (F, Js, 4, 4)``), ``kind``
    (``"bvh"``/``"gltf"``/``"character"``) and ``name`` (file name, for messages).
    """

    name: str
    joint_names: list[str]
    parents: np.ndarray
    rest_local: np.ndarray
    clip: Clip
    kind: str = "bvh"

    @classmethod
    def from_character(cls, character: Character, clip: str | Clip, kind: str = "character") -> MotionSource:
        """A clip of a loaded character (glTF or built-in) as a motion source."""
        c = character.clip(clip)
        return cls(character.name, list(character.joint_names), character.parents, character.bind_local, c, kind)


def load_motion(path: str | os.PathLike[str], clip: str | None = None, fps: float = 30.0) -> MotionSource:
    """Read a motion file: ``.bvh`` (its one clip) or ``.glb``/``.gltf`` (clip ``clip``, default the first,
    sampled at ``fps``). A missing or malformed file is a one-line :class:`PrtError`."""
    path = Path(path)
    check(path.is_file(), f"motion file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from prt_torch.rig.bvh import load_bvh

        skel, c = load_bvh(path)
        check(clip is None, f"{path.name}: a BVH file has one clip (got clip {clip!r})")
        return MotionSource(path.name, list(skel.joint_names), skel.parents, skel.bind_local, c, "bvh")
    if suffix in (".glb", ".gltf"):
        from prt_torch.rig.gltf import load_gltf

        ch = load_gltf(path, fps=fps)
        check(len(ch.clips) > 0, f"{path.name}: the glTF file has no animation to retarget")
        name = clip if clip is not None else next(iter(ch.clips))
        check(name in ch.clips, f"{path.name}: no clip {name!r}; available: {sorted(ch.clips)}")
        src = MotionSource.from_character(ch, name, "gltf")
        src.name = path.name
        return src
    raise PrtError(f"unknown motion file format {path.suffix!r}: {path.name} (expected .bvh, .glb or .gltf)")


@dataclass
class RetargetReport:
    """What :func:`retarget` did: families, the joint map used, leg-length scale, timing, limit hits, and what
    was detected: ``source_units`` (name) / ``source_height`` (rest joints' height, file units), ``facing``
    (what gave each skeleton's facing direction: ``toes``, ``eyes``, ``names``, ``default -y``),
    ``reference_jump_deg`` (frame 0 to 1 largest joint change), ``warnings`` (one-line ``warning: ...`` each,
    for every fix-up: a dropped reference-pose frame, a unit other than the target's).

    ``frames_clamped``: frames where any joint exceeded its limit by more than ``tol_deg`` (and was
    clamped); ``clamped_frames`` / ``max_excess_deg``: per target joint, the frames over the limit and the
    largest excess in degrees (joints that never exceeded it are absent).
    """

    source: str
    target: str
    source_family: str
    target_family: str
    joint_map: dict[str, str]
    unmapped_source: list[str]
    unmapped_target: list[str]
    scale: float
    fps: float
    frames: int
    skipped_first: bool
    frames_clamped: int = 0
    clamped_frames: dict[str, int] = field(default_factory=dict)
    max_excess_deg: dict[str, float] = field(default_factory=dict)
    source_units: str = "metres"
    source_height: float = 0.0
    facing: tuple[str, str] = ("", "")
    reference_jump_deg: float = 0.0
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """One line for logs."""
        worst = sorted(self.clamped_frames.items(), key=lambda kv: -kv[1])[:3]
        hits = ", ".join(f"{j} {n}" for j, n in worst)
        skipped = " (reference-pose frame skipped)" if self.skipped_first else ""
        return (f"{self.source} ({self.source_family or 'custom'}) -> {self.target}: {len(self.joint_map)} joints "
                f"mapped, {self.frames} frames at {self.fps:g} fps{skipped}"
                f", root scale {self.scale:.4g}; {self.frames_clamped} frames hit a joint limit"
                f"{f' ({hits})' if hits else ''}; source in {self.source_units}"
                + "".join(f"; {w}" for w in self.warnings))


# -- small vectorised helpers ---------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _rot(m: np.ndarray) -> np.ndarray:
    """Pure rotation ``(..., 3, 3)`` of transforms ``(..., 4, 4)`` (column scale removed)."""
    r = m[..., :3, :3]
    return r / np.linalg.norm(r, axis=-2, keepdims=True)


def align_vectors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotations ``(..., 3, 3)`` taking unit vectors ``a (..., 3)`` onto ``b (..., 3)``.

    Rodrigues about ``a x b``; opposite vectors turn by 180 degrees about an axis perpendicular to ``a``.
    """
    a, b = np.broadcast_arrays(_unit(np.asarray(a, float)), _unit(np.asarray(b, float)))
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)
    k = np.zeros(v.shape + (3,))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    opposite = c < -1.0 + 1e-9
    denom = np.where(opposite, 1.0, 1.0 + c)[..., None, None]
    r = np.eye(3) + k + (k @ k) / denom
    if np.any(opposite):
        e = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
        n = _unit(np.cross(a, e))
        flip = 2.0 * n[..., :, None] * n[..., None, :] - np.eye(3)
        r = np.where(opposite[..., None, None], flip, r)
    return r


def limit_angles_of(rel: np.ndarray) -> np.ndarray:
    """Angles ``(..., 3)`` = ``(a_x, a_y, a_z)`` of bind-relative rotations ``rel (..., 3, 3)`` =
    ``R_x(a_x) R_z(a_z) R_y(a_y)`` (as :func:`prt_torch.rig.random_pose.limit_angles`)."""
    from scipy.spatial.transform import Rotation

    xzy = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler("XZY").reshape(*rel.shape[:-2], 3)
    return xzy[..., [0, 2, 1]]


def compose_angles(angles: np.ndarray) -> np.ndarray:
    """``R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` ``(..., 3, 3)`` of angles ``(..., 3)`` = ``(a_x, a_y, a_z)``."""
    return (axis_angle_matrix([1.0, 0.0, 0.0], angles[..., 0]) @ axis_angle_matrix([0.0, 0.0, 1.0], angles[..., 2])
            @ axis_angle_matrix([0.0, 1.0, 0.0], angles[..., 1]))


# -- joint map ------------------------------------------------------------------------------------
@dataclass
class _Map:
    pairs: dict[int, int]  # target joint -> source joint
    roles: dict[int, str]  # target joint -> role (when known)
    source_family: str
    target_family: str
    facing: tuple[str, str] = ("", "")  # what gave each side's facing direction
    notes: list[str] = field(default_factory=list)


def _rest_positions(parents: np.ndarray, local: np.ndarray) -> np.ndarray:
    return forward_kinematics(parents, local[None])[0][:, :3, 3]


def build_joint_map(source: MotionSource, target: Character,
                    joint_map: Mapping[str, str | None] | None = None) -> _Map:
    """Pair source and target joints by structural role (:func:`prt_torch.rig.joint_map.find_roles`), apply the
    ``joint_map`` override, check both are humanoid. A skeleton whose structure is not humanoid is a one-line
    :class:`PrtError` naming why, unless ``joint_map`` is given (then the override alone pairs it)."""
    s_rest = _rest_positions(source.parents, source.rest_local)
    t_rest = _rest_positions(target.parents, target.bind_local)
    found = []
    for which, who, names, parents, rest in (("source", source.name, source.joint_names, source.parents, s_rest),
                                             ("target", repr(target.name), target.joint_names, target.parents,
                                              t_rest)):
        try:
            found.append(find_roles(list(names), parents, rest, f"{which} {who}"))
        except PrtError as e:
            if not joint_map:
                raise PrtError(f"cannot retarget {source.name} onto {target.name!r}: not a humanoid pair: {e} "
                               f"(or set joint_map)") from None
            found.append(None)
    s_found, t_found = found
    s_roles = s_found.roles if s_found else {}
    t_roles = t_found.roles if t_found else {}
    pairs = {t_roles[r]: s_roles[r] for r in ROLES if r in s_roles and r in t_roles}
    roles = {t: r for r, t in t_roles.items()}
    s_index = {n: i for i, n in enumerate(source.joint_names)}
    t_index = {n: i for i, n in enumerate(target.joint_names)}
    s_role_of = {i: r for r, i in s_roles.items()}
    for s_name, t_name in (joint_map or {}).items():
        if s_name not in s_index:
            raise PrtError(f"joint_map: unknown source joint {s_name!r} in {source.name} "
                           f"(joints: {', '.join(source.joint_names[:8])}, ...)")
        s = s_index[s_name]
        pairs = {t: si for t, si in pairs.items() if si != s}
        if t_name is None:
            continue
        if t_name not in t_index:
            raise PrtError(f"joint_map: unknown target joint {t_name!r} of character {target.name!r} "
                           f"(joints: {', '.join(target.joint_names[:8])}, ...)")
        t = t_index[t_name]
        pairs[t] = s
        if t not in roles and s in s_role_of:
            roles[t] = s_role_of[s]
        if t not in roles and not t_found:  # the target's roles come from the source's (structure or names)
            fam_role = {i: r for r, i in detect_roles(source.joint_names)[1].items()}
            if s in fam_role:
                roles[t] = fam_role[s]
    mapped_roles = {roles[t] for t in pairs if t in roles}
    missing = [r for r in REQUIRED if not any(x in mapped_roles for x in r.split("|"))]
    if missing:
        raise PrtError(f"cannot retarget {source.name} onto {target.name!r}: not a humanoid pair, only "
                       f"{len(REQUIRED) - len(missing)} of the {len(REQUIRED)} required humanoid joints map "
                       f"(missing: {', '.join(missing)}; or set joint_map)")
    by_role = {roles[t]: (t, s) for t, s in pairs.items() if t in roles}
    for which, who, rest, k in (("source", source.name, s_rest, 1), ("target", target.name, t_rest, 0)):
        up = rest[by_role["head"][k]] - rest[by_role["pelvis"][k]]
        ang = np.degrees(np.arccos(np.clip(up[2] / max(np.linalg.norm(up), 1e-12), -1, 1)))
        knees_low = all(rest[by_role[f"knee_{s}"][k], 2] < rest[by_role[f"hip_{s}"][k], 2] for s in "lr")
        if ang > HEAD_UP_MAX_DEG or not knees_low:
            knees = "" if knees_low else ", knees not below hips"
            raise PrtError(f"cannot retarget: the {which} skeleton {who!r} is not an upright humanoid at rest "
                           f"(pelvis-to-head {ang:.0f} degrees from vertical{knees}"
                           f"; quadrupeds such as Fox are not supported)")
    facing = (s_found.facing_from if s_found else "joint_map", t_found.facing_from if t_found else "joint_map")
    notes = [n for f in found if f for n in f.notes]
    return _Map(pairs, roles, detect_roles(source.joint_names)[0], detect_roles(target.joint_names)[0], facing,
                notes)


def reference_frame(local: np.ndarray, rest_local: np.ndarray) -> tuple[bool, float]:
    """Whether frame 0 of ``local (F, J, 4, 4)`` is a converter's reference pose (see the module docstring),
    and its largest joint jump to frame 1 in degrees. ``rest_local (J, 4, 4)``: the zero-channel pose."""
    if len(local) < 3:
        return False, 0.0

    def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        r = np.swapaxes(_rot(a), -1, -2) @ _rot(b)
        return np.degrees(np.arccos(np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)))

    at_rest = angle(local[0], rest_local)  # (J,)
    jump = float(angle(local[0], local[1]).max())
    steps = angle(local[1:min(len(local), 121) - 1], local[2:min(len(local), 121)]).max(axis=1)
    typical = float(np.percentile(steps, 90))
    is_ref = (float(np.median(at_rest[1:])) < 0.5 and float(at_rest[0]) < 0.5
              and jump > max(REFERENCE_JUMP_DEG, REFERENCE_JUMP_RATIO * typical))
    return is_ref, jump


def flight_frame_rate(source: MotionSource, by_role: Mapping[str, int], unit_m: float) -> float | None:
    """The frame rate (a :data:`FRAME_RATES` entry) that makes the source's flight phases fall at ``g``, or ``None``.

    Flight: runs of at least 10 frames with both ankles above their median level (the lower ankle's) by 0.1
    of the rest standing height; on each, a parabola fit of the pelvis height (``R^2 > 0.99``, curving down)
    gives ``a`` (units / frame^2) and ``dt = sqrt(-a unit_m / 9.81)``; the frames-weighted median ``dt``
    rounded to the nearest standard rate. Needs the pelvis and both ankles mapped.
    """
    if not all(r in by_role for r in ("pelvis", "ankle_l", "ankle_r")) or source.clip.num_frames < 10:
        return None
    pel, al, ar = by_role["pelvis"], by_role["ankle_l"], by_role["ankle_r"]
    rest = _rest_positions(source.parents, source.rest_local)
    stand = rest[pel, 2] - (rest[al, 2] + rest[ar, 2]) / 2
    w = forward_kinematics(source.parents, source.clip.local)[..., :3, 3]
    low = np.minimum(w[:, al, 2], w[:, ar, 2])
    air = np.concatenate([[False], low > np.median(low) + 0.1 * stand, [False]])
    edges = np.flatnonzero(np.diff(air.astype(int)))
    dts, weights = [], []
    for i, j in zip(edges[::2], edges[1::2], strict=True):
        if j - i < 10:
            continue
        z = w[i:j, pel, 2]
        t = np.arange(j - i, dtype=float)
        coef = np.polyfit(t, z, 2)
        res = z - np.polyval(coef, t)
        r2 = 1.0 - float(res @ res) / max(float(np.sum((z - z.mean()) ** 2)), 1e-300)
        if coef[0] < 0 and r2 > 0.99:  # free fall is a clean parabola (climbing, hanging: not)
            dts.append(np.sqrt(-2.0 * coef[0] * unit_m / 9.81))
            weights.append(j - i)
    if not dts:
        return None
    order = np.argsort(dts)
    cum = np.cumsum(np.asarray(weights)[order])
    dt = float(np.asarray(dts)[order][np.searchsorted(cum, cum[-1] / 2)])
    return min(FRAME_RATES, key=lambda f: abs(np.log(f * dt)))


def detect_units(source_height: float, target_height_m: float) -> tuple[str, float]:
    """``(unit name, metres per unit)``: the :data:`UNITS` entry nearest (in log) to the metres per source unit
    that make the source's rest height (``source_height``, file units) the target's (``target_height_m``)."""
    per = target_height_m / max(source_height, 1e-12)
    name = min(UNITS, key=lambda u: abs(np.log(UNITS[u] / per)))
    return name, UNITS[name]


# -- retargeting ----------------------------------------------------------------------------------
def _align_frames(u_s: np.ndarray, h_s: np.ndarray, u_t: np.ndarray, h_t: np.ndarray) -> np.ndarray:
    """The rotation ``(3, 3)`` taking ``u_s`` onto ``u_t`` and ``h_s`` (made orthogonal to ``u_s``) onto ``h_t``
    (orthogonal to ``u_t``); the minimal rotation when either ``h`` is (nearly) parallel to its ``u``."""
    def frame(u: np.ndarray, h: np.ndarray) -> np.ndarray | None:
        h = h - (h @ u) * u
        if np.linalg.norm(h) < 0.2:
            return None
        h = _unit(h)
        return np.stack([u, h, np.cross(u, h)], axis=1)

    fs, ft = frame(u_s, h_s), frame(u_t, h_t)
    return align_vectors(u_s, u_t) if fs is None or ft is None else ft @ fs.T


def _hinge_axes(target: Character, pairs: dict[int, int], children: dict[int, list[int]],
                bone: Callable[[int], int | None], rs: np.ndarray,
                rs0: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Twist alignment of hinge limbs: ``{target joint: (source hinge axis, target hinge axis)}`` (rest world).

    A target joint ``H`` is a hinge when its joint limits free ``a_x`` only (elbows, knees of the built-in
    humanoid); its axis is ``+-x`` of its rest frame (the sign making flexion positive). The source's axis is
    estimated from the motion: ``(P->H) x (H->C)`` (``P`` its mapped parent, ``C`` its primary child),
    taken back to the source rest frame of ``P`` and averaged (bigger bends weigh more). ``H`` and ``P`` then
    align ``(bone, axis)`` frames instead of the bone direction alone (a twist about the bone: directions are
    unchanged), so the source's flexion lands on the target's hinge instead of being clamped away.
    """
    from scipy.spatial.transform import Rotation

    lim = target.joint_limits
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if lim is None:
        return out
    parent_of = {c: p for p, cs in children.items() for c in cs}
    for h, p in parent_of.items():
        free = lim[h, :, 1] - lim[h, :, 0]
        if not (free[0] > 0 and free[1] == 0 and free[2] == 0) or children[p] != [h]:
            continue
        if bone(h) is None or bone(p) != h:
            continue
        sp, sh = pairs[p], pairs[h]
        rel = np.swapaxes(rs[:, sp] @ rs0[sp].T, -1, -2) @ (rs[:, sh] @ rs0[sh].T)  # D_P^T D_H (F, 3, 3)
        rest_axis = Rotation.from_matrix(rel).as_rotvec().sum(axis=0)  # angle-weighted sum of the axes
        if np.linalg.norm(rest_axis) < np.radians(3.0) * len(rel):
            continue  # the limb hardly bends: keep the minimal alignment
        sign = -1.0 if lim[h, 0, 1] <= 0 else 1.0
        h_t = sign * _rot(forward_kinematics(target.parents, target.bind_local[None])[0, h])[:, 0]
        out[p] = out[h] = (_unit(rest_axis), h_t)
    return out


def _leg_length(rest: np.ndarray, by_role: dict[str, int]) -> float:
    """Mean over sides of pelvis-to-hip height + thigh + shin length at rest (``rest (J, 3)`` positions)."""
    out = []
    for s in "lr":
        hip, knee = rest[by_role[f"hip_{s}"]], rest[by_role[f"knee_{s}"]]
        low = rest[by_role[f"ankle_{s}"]] if f"ankle_{s}" in by_role else knee + (knee - hip)
        out.append(abs(rest[by_role["pelvis"], 2] - hip[2]) + np.linalg.norm(knee - hip) + np.linalg.norm(low - knee))
    return float(np.mean(out))


def retarget(source: MotionSource, target: Character, fps: float | None = None,
             joint_map: Mapping[str, str | None] | None = None, name: str | None = None,
             skip_first: bool | None = None, tol_deg: float = 0.5) -> tuple[Clip, RetargetReport]:
    """Retarget ``source`` onto ``target`` -> ``(Clip (F, J, 4, 4) of the target at fps, RetargetReport)``.

    ``fps``: output rate (default: the source's); ``joint_map``: ``{source joint: target joint or None}``
    overrides; ``skip_first``: drop the source's frame 0 (default: when :func:`reference_frame` detects a
    converter's reference pose there);
    ``tol_deg``: limit excess counted as a hit. See the module docstring for the rule.
    """
    m = build_joint_map(source, target, joint_map)
    warnings: list[str] = [f"warning: {source.name}: {n}" for n in m.notes]
    detected, jump = reference_frame(source.clip.local, source.rest_local)
    if skip_first is None:
        skip_first = detected
        if detected:
            warnings.append(f"warning: {source.name}: frame 1 is a converter's reference pose (the rest pose, "
                            f"{jump:.0f} degrees from frame 2): skipped")
    s_height = float(np.ptp(_rest_positions(source.parents, source.rest_local)[:, 2]))
    t_height = float(np.ptp(_rest_positions(target.parents, target.bind_local)[:, 2]))
    units, unit_m = detect_units(s_height, t_height)
    clip = source.clip
    s_by_role = {r: m.pairs[t] for t, r in m.roles.items() if t in m.pairs}
    rate = flight_frame_rate(source, s_by_role, unit_m)
    if rate is not None and not 1 / 1.5 < rate / clip.fps < 1.5:
        warnings.append(f"warning: {source.name}: the header's {clip.fps:.4g} fps does not fit the flight phases' "
                        f"gravity ({rate:.4g} fps): played at {rate:.4g} fps")
        clip = Clip(clip.name, rate, clip.local)
    if skip_first:
        check(clip.num_frames > 1, f"{source.name}: only one frame, nothing left after skipping the T-pose frame")
        clip = Clip(clip.name, clip.fps, clip.local[1:])
    fps = clip.fps if fps is None else float(fps)
    check(bool(np.isfinite(fps)) and fps > 0, f"fps must be > 0, got {fps}")
    if abs(fps - clip.fps) > 1e-9:
        clip = clip.resample(fps)
    n = clip.num_frames
    ws = forward_kinematics(source.parents, clip.local)  # (F, Js, 4, 4)
    ws0 = forward_kinematics(source.parents, source.rest_local[None])[0]
    wt0 = forward_kinematics(target.parents, target.bind_local[None])[0]
    rs, ps = _rot(ws), ws[..., :3, 3]
    rs0, ps0 = _rot(ws0), ws0[:, :3, 3]
    rt0, pt0 = _rot(wt0), wt0[:, :3, 3]
    check(bool(np.all(np.isfinite(ws))), f"{source.name}: posed skeleton has NaN or inf")

    pairs = m.pairs
    by_role_t = {r: t for t, r in m.roles.items() if t in pairs}
    by_role_s = {r: pairs[t] for r, t in by_role_t.items()}
    ankles = all(f"ankle_{x}" in by_role_t for x in "lr")
    if ankles:
        stand_t, stand_s = (float(p[r["pelvis"], 2] - (p[r["ankle_l"], 2] + p[r["ankle_r"], 2]) / 2)
                            for p, r in ((pt0, by_role_t), (ps0, by_role_s)))
        check(stand_t > 0 and stand_s > 0, f"{source.name}: the pelvis is not above the ankles at rest")
        scale = stand_t / stand_s
    else:
        scale = _leg_length(pt0, by_role_t) / _leg_length(ps0, by_role_s)
    if units != "metres":
        warnings.append(f"warning: {source.name}: lengths in {units} (rest height {s_height:.4g} vs the target's "
                        f"{t_height:.3g} m): root motion scaled by {scale:.4g}")
    eps_t, eps_s = 1e-4 * _leg_length(pt0, by_role_t), 1e-4 * _leg_length(ps0, by_role_s)

    # mapped hierarchy: each mapped target joint's nearest mapped target ancestor
    jt = target.num_joints
    up_mapped = np.full(jt, -1)
    for j in range(jt):
        p = int(target.parents[j])
        while p >= 0 and p not in pairs:
            p = int(target.parents[p])
        up_mapped[j] = p
    s_anc = [set() for _ in source.joint_names]
    for j, p in enumerate(source.parents):
        if p >= 0:
            s_anc[j] = s_anc[int(p)] | {int(p)}
    children: dict[int, list[int]] = {t: [] for t in pairs}
    for c in pairs:
        p = int(up_mapped[c])
        if p >= 0 and pairs[p] in s_anc[pairs[c]]:
            children[p].append(c)

    def primary(t: int) -> int | None:
        cands = children[t]
        if not cands:
            return None
        return max(cands, key=lambda c: (_unit(pt0[c] - pt0[t])[2], -c))

    def bone(t: int) -> int | None:
        """The primary child at a non-zero distance in both skeletons (``None``: a leaf)."""
        c = primary(t)
        while c is not None and (np.linalg.norm(pt0[c] - pt0[t]) < eps_t
                                 or np.linalg.norm(ps0[pairs[c]] - ps0[pairs[t]]) < eps_s):
            c = primary(c)
        return c

    hinges = _hinge_axes(target, pairs, children, bone, rs, rs0)
    world = {}  # target joint -> desired world rotation (F, 3, 3)
    a_of: dict[int, np.ndarray] = {}
    for t in sorted(pairs):
        s = pairs[t]
        d = rs[:, s] @ rs0[s].T  # (F, 3, 3) world delta of the source joint
        c = bone(t)
        if c is None:  # leaf: the parent bone's alignment
            p = int(up_mapped[t])
            a = a_of.get(p, np.eye(3))
        else:
            u_s = _unit(ps0[pairs[c]] - ps0[s])
            u_t = _unit(pt0[c] - pt0[t])
            a = align_vectors(u_s, u_t) if t not in hinges else _align_frames(u_s, hinges[t][0], u_t, hinges[t][1])
            if len(children[t]) == 1:  # fold unmapped joints in between: follow the actual source bone
                d = align_vectors(d @ u_s, _unit(ps[:, pairs[c]] - ps[:, s])) @ d
        a_of[t] = a
        world[t] = d @ a.T @ rt0[t]

    # root motion of the pelvis-mapped joint
    pelvis = by_role_t["pelvis"]
    sp = by_role_s["pelvis"]
    floor = float(np.min(target.rest_vertices[:, 2]))
    p_des = np.empty((n, 3))
    p_des[:, :2] = pt0[pelvis, :2] + scale * (ps[:, sp, :2] - ps[0, sp, :2])
    if ankles:
        a_src = float(np.percentile(np.minimum(ps[:, by_role_s["ankle_l"], 2], ps[:, by_role_s["ankle_r"], 2]), 50))
        h_ankle = (pt0[by_role_t["ankle_l"], 2] + pt0[by_role_t["ankle_r"], 2]) / 2 - floor
        p_des[:, 2] = floor + h_ankle + scale * (ps[:, sp, 2] - a_src)
    else:
        p_des[:, 2] = floor + scale * ps[:, sp, 2]

    # back to local transforms, hierarchy order, with joint limits
    lim = target.joint_limits
    local = np.tile(target.bind_local, (n, 1, 1, 1))
    wnew = np.empty_like(local)
    clamped = np.zeros(n, dtype=bool)
    counts: dict[str, int] = {}
    excess_max: dict[str, float] = {}
    for j in range(jt):
        p = int(target.parents[j])
        if j in pairs:
            sw = np.linalg.norm(wt0[j, :3, :3], axis=0)
            want = world[j] * sw[None, None, :]
            rl = want if p < 0 else np.linalg.solve(wnew[:, p, :3, :3], want)
            if lim is not None and p >= 0:
                rb = target.bind_local[j, :3, :3]
                ang = limit_angles_of(rb.T @ rl)
                cl = np.clip(ang, lim[j, :, 0], lim[j, :, 1])
                exc = np.max(np.abs(ang - cl), axis=-1)
                fix = exc > 1e-9
                if np.any(fix):
                    rl = np.where(fix[:, None, None], rb @ compose_angles(cl), rl)
                hit = exc > np.radians(tol_deg)
                if np.any(hit):
                    clamped |= hit
                    counts[target.joint_names[j]] = int(hit.sum())
                    excess_max[target.joint_names[j]] = float(np.degrees(exc.max()))
            local[:, j, :3, :3] = rl
            if j == pelvis:
                local[:, j, :3, 3] = p_des if p < 0 else np.linalg.solve(
                    wnew[:, p], np.concatenate([p_des, np.ones((n, 1))], axis=1)[..., None])[:, :3, 0]
        wnew[:, j] = local[:, j] if p < 0 else wnew[:, p] @ local[:, j]
    check(bool(np.all(np.isfinite(local))), f"{source.name}: retargeted pose has NaN or inf")
    out = Clip(name or Path(source.name).stem, fps, local)
    tnames, snames = target.joint_names, source.joint_names
    report = RetargetReport(
        source=source.name, target=target.name, source_family=m.source_family, target_family=m.target_family,
        joint_map={snames[s]: tnames[t] for t, s in sorted(pairs.items())},
        unmapped_source=[snames[i] for i in range(len(snames)) if i not in pairs.values()],
        unmapped_target=[tnames[i] for i in range(jt) if i not in pairs], scale=float(scale), fps=fps, frames=n,
        skipped_first=bool(skip_first), frames_clamped=int(clamped.sum()), clamped_frames=counts,
        max_excess_deg=excess_max, source_units=units, source_height=s_height, facing=m.facing,
        reference_jump_deg=jump, warnings=warnings)
    return out, report


def retarget_file(path: str | os.PathLike[str], target: Character, fps: float | None = None,
                  joint_map: Mapping[str, str | None] | None = None, name: str | None = None,
                  skip_first: bool | None = None, clip: str | None = None) -> tuple[Clip, RetargetReport]:
    """:func:`load_motion` + :func:`retarget` (``fps`` default: the target's first clip's rate, else 30)."""
    if fps is None:
        fps = next(iter(target.clips.values())).fps if target.clips else 30.0
    src = load_motion(path, clip=clip, fps=fps)
    return retarget(src, target, fps=fps, joint_map=joint_map, name=name or Path(path).stem, skip_first=skip_first)
