"""The structural humanoid joint map: humanoid roles found from a skeleton's topology and rest geometry.

numpy only. Input: joint names ``(J,)``, ``parents (J,)`` (``-1`` = root) and rest world joint positions
``rest (J, 3)`` in the z-up world (BVH and glTF loaders convert to it). Names are used only as tie-breakers
(an end marker leaf such as ``HeadTop_End`` at the top of the spine; the side when the rest pose gives no
facing direction), so prefixes, suffixes, case, separators and joint order do not change the map.

Rule (``H`` = the rest joints' height extent):

* **Legs.** Joints whose whole subtree lies within ``0.15 H`` of the lowest joint reach the ground (a
  floor-level root above the pelvis does not); two of them belong to one limb
  when their lowest common ancestor is below ``0.3 H``. A humanoid has exactly two such limbs (a quadruped
  has four: refused). The *pelvis* is the lowest common ancestor of the two limb tips (the lowest joint of
  each); each leg chain runs from the pelvis's child to its tip.
* **Spine.** From the pelvis (or, when the legs hang off a sub-pelvis, its first ancestor with one), the
  child subtree that reaches highest, followed up through the child that reaches highest, to a leaf. A top
  leaf that has a mirrored leaf sibling (eyes) or whose name is an end marker is dropped: the *head* is the
  top of the spine chain. The head must be within 50 degrees of vertical above the pelvis.
* **Sides.** The lateral axis is the horizontal difference of the two legs' mean positions; the facing
  direction is the horizontal ankle-to-toe direction (or the head-to-eyes direction, or, failing both,
  the legs' names, or the z-up world's convention ``-y``); left = ``up x forward``.
* **Arms.** The largest subtree on each side branching off the spine chain (between pelvis and head, at
  least ``0.35`` leg lengths long); each arm chain runs to its farthest joint. The *chest* is the spine
  joint the arms branch from (the lower one if they differ), *spine* the pelvis's child on the chain (when
  it is not the chest), *neck* the chest's child on the chain (when it is not the head).
* **Limb joints.** Leg: the *ankle* is the first chain joint less than ``0.2`` of the chain's height above
  its tip, the *toe* the joint after it. Arm: the *wrist* is the first chain joint (after two) that branches
  into a hand-sized subtree (fingers), else the chain's last joint. *Hip/knee* and *shoulder/elbow* are the
  pair of joints before the ankle / wrist whose two segments (to each other, then to the ankle / wrist) are
  most nearly equal and straight (a joint off the segment's line is a real joint, one on it a twist
  helper): score ``|a - b| / (a + b) + 5 (straightness excess)``. The *clavicle* is the arm joint before
  the shoulder. Fingers, eyes, twist and extra joints (CMU ``LHipJoint``, Daz ``lButtock``) stay unmapped.

Limitation: twist helpers as leaves (siblings of the next limb joint, as in Unreal-style rigs) are ignored,
but a twist joint *inside* a limb chain (``elbow -> twist -> wrist``) at mid-bone can win the pairing (its
two halves are perfectly equal and straight): map such rigs with ``joint_map``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from prt_torch.errors import PrtError

GROUND_FRACTION = 0.15
LIMB_LCA_FRACTION = 0.3
HEAD_UP_MAX_DEG = 50.0
ARM_MIN_LEG_FRACTION = 0.35
ANKLE_FRACTION = 0.2
STRAIGHT_WEIGHT = 5.0
_END_TOKENS = frozenset({"end", "nub", "top", "tip", "site", "headtop", "end_site"})


def name_tokens(name: str) -> list[str]:
    """Lower-case word tokens of a joint name: a ``prefix:`` dropped, split at separators, digits and
    camel case (``mixamorig:HeadTop_End`` -> ``['head', 'top', 'end']``)."""
    n = name.rsplit(":", 1)[-1]
    n = re.sub(r"([a-z])([A-Z])", r"\1 \2", n)
    return [t for t in re.split(r"[^A-Za-z]+", n.lower()) if t]


def name_side(name: str) -> int:
    """``+1`` for a left-named joint, ``-1`` right, ``0`` neither (a name tie-breaker only)."""
    toks = name_tokens(name)
    left = any(t in ("l", "left", "lft") or t.startswith("left") for t in toks)
    right = any(t in ("r", "right", "rgt") or t.startswith("right") for t in toks)
    if not (left or right):
        base = name.rsplit(":", 1)[-1]
        left, right = bool(re.match(r"^l[A-Z]", base)), bool(re.match(r"^r[A-Z]", base))
    return int(left) - int(right)


@dataclass
class SkeletonRoles:
    """Humanoid roles of one skeleton: ``roles {role: joint index}`` (the built-in humanoid's names, see
    :mod:`prt_torch.rig.retarget`), the rest frame's ``forward``/``left`` unit vectors ``(3,)`` (z up),
    ``facing_from`` (what gave the facing direction), ``height`` (rest joints' z extent, file units)."""

    roles: dict[str, int]
    forward: np.ndarray
    left: np.ndarray
    facing_from: str
    height: float
    notes: list[str] = field(default_factory=list)


class _Tree:
    def __init__(self, parents: np.ndarray, rest: np.ndarray) -> None:
        self.parents = [int(p) for p in parents]
        self.rest = rest
        self.children: list[list[int]] = [[] for _ in self.parents]
        for j, p in enumerate(self.parents):
            if p >= 0:
                self.children[p].append(j)
        self.anc: list[list[int]] = []  # root .. j
        for j in range(len(self.parents)):
            chain = [j]
            while self.parents[chain[-1]] >= 0 and len(chain) <= len(self.parents):
                chain.append(self.parents[chain[-1]])
            self.anc.append(chain[::-1])
        self.sub: list[list[int]] = [[] for _ in self.parents]  # j and its descendants
        for j, a in enumerate(self.anc):
            for i in a:
                self.sub[i].append(j)
        z = rest[:, 2]
        self.top = np.array([z[s].max() for s in self.sub])

    def lca(self, a: int, b: int) -> int:
        out = -1
        for x, y in zip(self.anc[a], self.anc[b], strict=False):
            if x != y:
                break
            out = x
        return out

    def path(self, a: int, b: int) -> list[int]:
        """Joints from ``a``'s child down to ``b`` (``a`` an ancestor of ``b``)."""
        chain = self.anc[b]
        return chain[chain.index(a) + 1:]

    def extent(self, j: int, frm: int) -> float:
        return float(np.max(np.linalg.norm(self.rest[self.sub[j]] - self.rest[frm], axis=1)))


def _limb_pair(rest: np.ndarray, cands: list[int], end: int, what: str) -> tuple[int, int]:
    """Indices ``(i, j)`` into ``cands`` of the upper and middle limb joints (see the module docstring)."""
    if len(cands) < 2:
        raise PrtError(f"{what}: the chain has {len(cands)} joint(s) above its end, needs two")
    pts = [rest[c] for c in cands] + [rest[end]]
    seg = np.array([np.linalg.norm(pts[k + 1] - pts[k]) for k in range(len(pts) - 1)])
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    best, out = np.inf, (0, 1)
    tiny = 1e-6 * max(arc[-1], 1e-12)
    last = len(pts) - 1
    for i in range(len(cands) - 1):
        for j in range(i + 1, len(cands)):
            a, b = np.linalg.norm(pts[j] - pts[i]), np.linalg.norm(pts[last] - pts[j])
            if a < tiny or b < tiny:
                continue
            excess = max((arc[j] - arc[i]) / a, (arc[last] - arc[j]) / b) - 1.0
            score = abs(a - b) / (a + b) + STRAIGHT_WEIGHT * excess
            if score < best - 1e-9:
                best, out = score, (i, j)
    return out


def find_roles(names: list[str], parents: np.ndarray, rest: np.ndarray, what: str) -> SkeletonRoles:
    """Humanoid roles of a skeleton from its structure (see the module docstring).

    ``names (J,)``, ``parents (J,)``, ``rest (J, 3)`` rest world positions (z up); ``what`` names the skeleton
    in messages. A skeleton that is not an upright biped (Fox: four limbs reach the ground) raises a one-line
    :class:`PrtError` saying why.
    """
    rest = np.asarray(rest, float)
    t = _Tree(np.asarray(parents), rest)
    z = rest[:, 2]
    height = float(np.ptp(z)) if len(z) else 0.0
    if len(names) < 9 or not height > 0:
        raise PrtError(f"{what}: {len(names)} joints, {height:.3g} tall at rest: too few for a humanoid")
    zmin = float(z.min())
    ground = [j for j in range(len(z)) if t.top[j] - zmin < GROUND_FRACTION * height]  # whole subtree low
    clusters: list[list[int]] = []
    for g in ground:
        for c in clusters:
            if z[t.lca(g, c[0])] - zmin < LIMB_LCA_FRACTION * height:
                c.append(g)
                break
        else:
            clusters.append([g])
    if len(clusters) != 2:
        kind = "; a quadruped?" if len(clusters) == 4 else ""
        raise PrtError(f"{what}: {len(clusters)} limb chains reach the ground at rest, a humanoid has 2{kind}")
    tips = [min(c, key=lambda j: (z[j], j)) for c in clusters]
    hips = t.lca(*tips)
    if hips < 0:
        raise PrtError(f"{what}: the two legs are in separate trees")
    legs = [t.path(hips, tip) for tip in tips]

    # spine: the child subtree of the pelvis (or an ancestor) that reaches highest
    pelvis, spine_root = hips, -1
    while pelvis >= 0:
        side = [c for c in t.children[pelvis] if c not in t.anc[tips[0]] and c not in t.anc[tips[1]]]
        if side:
            c = max(side, key=lambda c: (t.top[c], -c))
            if t.top[c] > z[hips] + 0.2 * height:
                spine_root = c
                break
        pelvis = t.parents[pelvis]
    if spine_root < 0:
        raise PrtError(f"{what}: no spine chain rises above the hips")
    chain = [spine_root]
    while t.children[chain[-1]]:
        chain.append(max(t.children[chain[-1]], key=lambda c: (t.top[c], -c)))
    lateral = rest[legs[0]].mean(axis=0) - rest[legs[1]].mean(axis=0)
    lateral[2] = 0.0
    if np.linalg.norm(lateral) < 1e-3 * height:
        raise PrtError(f"{what}: the legs are not side by side at rest")
    lateral /= np.linalg.norm(lateral)
    notes: list[str] = []
    eyes: list[int] = []
    top = chain[-1]
    if len(chain) > 2:
        par = t.parents[top]
        sibs = [c for c in t.children[par] if c != top and not t.children[c]]
        for s in sibs:
            d0, d1 = rest[top] - rest[par], rest[s] - rest[par]
            if (d0 @ lateral) * (d1 @ lateral) < 0 and abs(d0[2] - d1[2]) < 0.02 * height:
                eyes = [top, s]
        if eyes:
            chain.pop()
        elif not t.children[top] and _END_TOKENS & set(name_tokens(names[top])):
            chain.pop()
            notes.append(f"end joint {names[top]} above the head left unmapped")
    spine = [pelvis] + chain
    head = spine[-1]
    up = rest[head] - rest[pelvis]
    ang = float(np.degrees(np.arccos(np.clip(up[2] / max(np.linalg.norm(up), 1e-12), -1.0, 1.0))))
    if ang > HEAD_UP_MAX_DEG:
        raise PrtError(f"{what}: no upright spine at rest (pelvis-to-head {ang:.0f} degrees from vertical)")

    roles: dict[str, int] = {"pelvis": pelvis, "head": head}
    leg_roles = []
    for leg in legs:
        top_h = z[leg[0]] - z[leg[-1]]
        k = next((i for i in range(1, len(leg)) if z[leg[i]] - z[leg[-1]] < ANKLE_FRACTION * top_h), len(leg) - 1)
        i, j = _limb_pair(rest, leg[:k], leg[k], f"{what}: leg chain {names[leg[0]]}")
        r = {"hip": leg[i], "knee": leg[j], "ankle": leg[k]}
        if k + 1 < len(leg):
            r["toe"] = leg[k + 1]
        if not z[r["knee"]] < z[r["hip"]]:
            raise PrtError(f"{what}: the knee {names[r['knee']]} is not below the hip {names[r['hip']]} at rest")
        leg_roles.append(r)
    leg_len = float(np.mean([np.linalg.norm(rest[r["knee"]] - rest[r["hip"]])
                             + np.linalg.norm(rest[r["ankle"]] - rest[r["knee"]]) for r in leg_roles]))

    # facing: toes, else eyes, else names, else the z-up world's -y
    fwd = np.zeros(3)
    facing_from = ""
    for r in leg_roles:
        if "toe" in r:
            fwd += rest[r["toe"]] - rest[r["ankle"]]
    fwd[2] = 0.0
    fwd -= (fwd @ lateral) * lateral
    if np.linalg.norm(fwd) > 0.01 * height:
        facing_from = "toes"
    elif eyes:
        fwd = rest[eyes].mean(axis=0) - rest[head]
        fwd[2] = 0.0
        fwd -= (fwd @ lateral) * lateral
        if np.linalg.norm(fwd) > 0.005 * height:
            facing_from = "eyes"
    sign = 0.0
    if facing_from:
        sign = float(np.sign(np.cross([0.0, 0.0, 1.0], fwd) @ lateral))
    else:
        votes = sum(name_side(names[j]) for j in legs[0]) - sum(name_side(names[j]) for j in legs[1])
        if votes:
            sign, facing_from = float(np.sign(votes)), "names"
        else:
            sign, facing_from = float(np.sign(np.cross([0.0, 0.0, 1.0], [0.0, -1.0, 0.0]) @ lateral)), "default -y"
            sign = sign or 1.0
    left = lateral * sign
    forward = np.cross(left, [0.0, 0.0, 1.0])
    sides = {"l": leg_roles[0], "r": leg_roles[1]} if sign > 0 else {"l": leg_roles[1], "r": leg_roles[0]}
    for s, r in sides.items():
        roles.update({f"{k}_{s}": v for k, v in r.items()})

    # arms: the largest side subtree per side off the spine chain
    in_spine = set(spine)
    arms: dict[str, tuple[float, int, int]] = {}
    for si in spine[1:-1]:
        for c in t.children[si]:
            if c in in_spine:
                continue
            ext = t.extent(c, si)
            if ext < ARM_MIN_LEG_FRACTION * leg_len:
                continue
            far = max(t.sub[c], key=lambda d: (np.linalg.norm(rest[d] - rest[si]), -d))
            s = "l" if (rest[far] - rest[si]) @ left > 0 else "r"
            if s not in arms or ext > arms[s][0]:
                arms[s] = (ext, si, c)
    for s in "lr":
        if s not in arms:
            raise PrtError(f"{what}: no {'left' if s == 'l' else 'right'} arm chain branches off the spine")
    attach = sorted((arms["l"][1], arms["r"][1]), key=spine.index)
    chest = attach[0]
    ci = spine.index(chest)
    roles["chest"] = chest
    if ci > 1:
        roles["spine"] = spine[1]
    if ci + 1 < len(spine) - 1:
        roles["neck"] = spine[ci + 1]
    for s in "lr":
        _, si, c = arms[s]
        far = max(t.sub[c], key=lambda d: (np.linalg.norm(rest[d] - rest[si]), -d))
        arm = t.path(si, far)
        k = len(arm) - 1
        for i in range(2, len(arm)):
            kids = t.children[arm[i]]
            if len(kids) >= 2 and t.extent(arm[i], arm[i]) < 0.5 * np.linalg.norm(rest[arm[i]] - rest[arm[0]]):
                k = i
                break
        i, j = _limb_pair(rest, arm[:k], arm[k], f"{what}: arm chain {names[arm[0]]}")
        roles.update({f"shoulder_{s}": arm[i], f"elbow_{s}": arm[j], f"wrist_{s}": arm[k]})
        if i > 0:
            roles[f"clavicle_{s}"] = arm[i - 1]
    return SkeletonRoles(roles, forward, left, facing_from, height, notes)
