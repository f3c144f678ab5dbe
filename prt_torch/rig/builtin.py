"""The built-in procedural humanoid and its six motions (numpy only, deterministic).

Geometry: ~1.8 units tall, standing on ``z = 0``, **facing -y** (its left is ``+x``), z up. The
surface is the zero set of a smooth union (log-sum-exp smooth minimum, radius ``BLEND``) of
ellipsoids (pelvis, abdomen, chest, head) and tapered capsules (neck, clavicles, limbs, hands,
feet), extracted with surface nets (ambiguous cells resolved, so always a closed oriented
manifold; see :mod:`prt_torch.rig.surface_nets`) on a regular grid of spacing
``GRID_SPACING / sqrt(density)``, projected back onto the implicit surface by Newton steps and
relaxed tangentially. Below ``MIN_GRID_DENSITY`` the grid would miss wrists and toes, so the
surface is extracted at that density and decimated (VTK ``vtkDecimatePro``, topology preserving,
via pyvista). Rest normals are the implicit function's gradients (area-weighted mesh normals for
decimated meshes). The result is checked to be closed, 2-manifold, genus 0 and outward oriented;
``density=1`` gives ~11.7k vertices and the count scales ~linearly with ``density``.

Skeleton (21 joints, ``JOINT_NAMES``): pelvis (root) - spine - chest - neck - head; chest -
clavicle - shoulder - elbow - wrist per side; pelvis - hip - knee - ankle - toe per side. Bind pose:
an A-pose with the arms 45 degrees from the vertical and the legs slightly apart. Every joint's
bind frame is world aligned except the arm chain (shoulder, elbow, wrist), whose frames are rotated
so the arm lies along the local ``-z`` axis (then forward flexion of every limb is a rotation about
the local ``-x`` axis).

Skin weights: each surface part belongs to one joint; a vertex's weight for joint ``j`` is
``exp(-(d_p - d_min) / SKIN_FALLOFF)`` summed over ``j``'s parts (``d_p``: the part's distance
function), restricted to the skeleton neighbours (parent, children) of the vertex's nearest part's
joint (a soft mask, blended where the nearest part changes), smoothed over the mesh, reduced
to the top 4 and normalised.

Motions (30 fps, root motion is vertical/planted only, the character stays in place): ``walk``,
``run``, ``jumping_jacks``, ``squat``, ``wave``, ``stretch``. Feet are kept on the ground: each frame
the root is shifted so that the lowest foot joint keeps its bind height and the ankles' mean
horizontal position stays fixed (plus an explicit hop for jumps and runs).

Joint limits (for :func:`prt_torch.rig.random_pose.random_poses`) are in ``JOINT_LIMITS_DEG``:
bind-relative angles ``(a_x, a_y, a_z)`` composed ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)``, left side
given, right side mirrored (``a_y, a_z`` negated); the root is fixed at its bind pose.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from prt_torch.errors import check
from prt_torch.exact import small_matmul
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.mesh import vertex_normals
from prt_torch.rig.rotations import axis_angle_matrix, rigid_inverse
from prt_torch.rig.skeleton import forward_kinematics
from prt_torch.rig.surface_nets import surface_nets

NAME = "builtin-humanoid"
FPS = 30.0
GRID_SPACING = 0.0143  # metres at density 1
MIN_GRID_DENSITY = 0.2  # coarser grids lose wrists and toes; lower densities decimate
BLEND = 0.018  # smooth-union radius of the implicit surface
SKIN_FALLOFF = 0.03  # skin weight falloff distance
ARM_BIND_ELEVATION = 45.0  # degrees from straight down
ARM_REST_ELEVATION = 14.0  # arms hanging beside (not through) the torso in the motions
CLIP_NAMES = ("walk", "run", "jumping_jacks", "squat", "wave", "stretch")

# name, parent, bind world position (before grounding)
_SIDE = {"l": 1.0, "r": -1.0}
_SHOULDER = np.array([0.19, 0.0, 1.44])
_ARM_DIR = np.array([np.sin(np.radians(ARM_BIND_ELEVATION)), 0.0, -np.cos(np.radians(ARM_BIND_ELEVATION))])
UPPER_ARM, FOREARM, HAND = 0.28, 0.25, 0.17


def _joint_table() -> list[tuple[str, str | None, np.ndarray]]:
    t: list[tuple[str, str | None, np.ndarray]] = [
        ("pelvis", None, np.array([0.0, 0.0, 0.96])),
        ("spine", "pelvis", np.array([0.0, 0.0, 1.08])),
        ("chest", "spine", np.array([0.0, 0.0, 1.26])),
        ("neck", "chest", np.array([0.0, 0.0, 1.47])),
        ("head", "neck", np.array([0.0, 0.0, 1.58])),
    ]
    for s, sx in _SIDE.items():
        m = np.array([sx, 1.0, 1.0])
        sh = _SHOULDER * m
        el = sh + UPPER_ARM * _ARM_DIR * m
        wr = el + FOREARM * _ARM_DIR * m
        t += [(f"clavicle_{s}", "chest", np.array([0.03 * sx, 0.0, 1.43])), (f"shoulder_{s}", f"clavicle_{s}", sh),
              (f"elbow_{s}", f"shoulder_{s}", el), (f"wrist_{s}", f"elbow_{s}", wr)]
    for s, sx in _SIDE.items():
        t += [(f"hip_{s}", "pelvis", np.array([0.095 * sx, 0.0, 0.92])),
              (f"knee_{s}", f"hip_{s}", np.array([0.11 * sx, 0.0, 0.52])),
              (f"ankle_{s}", f"knee_{s}", np.array([0.12 * sx, 0.0, 0.10])),
              (f"toe_{s}", f"ankle_{s}", np.array([0.12 * sx, -0.13, 0.03]))]
    return t


JOINT_NAMES: list[str] = [n for n, _, _ in _joint_table()]
_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}


def _bind_world_rotations() -> np.ndarray:
    rots = np.tile(np.eye(3), (len(JOINT_NAMES), 1, 1))
    for s, sx in _SIDE.items():
        r = axis_angle_matrix([0.0, 1.0, 0.0], -sx * np.radians(ARM_BIND_ELEVATION))
        for j in ("shoulder", "elbow", "wrist"):
            rots[_IDX[f"{j}_{s}"]] = r
    return rots


# ---------------------------------------------------------------------------------------------
# implicit surface
@dataclass(frozen=True)
class _Part:
    joint: str
    kind: str  # "capsule" | "ellipsoid"
    a: tuple[float, float, float]  # capsule start / ellipsoid centre
    b: tuple[float, float, float]  # capsule end / ellipsoid radii
    ra: float = 0.0
    rb: float = 0.0


def _parts() -> list[_Part]:
    jp = {n: p for n, _, p in _joint_table()}
    P: list[_Part] = [
        _Part("pelvis", "ellipsoid", (0.0, 0.01, 0.95), (0.165, 0.11, 0.11)),
        _Part("spine", "ellipsoid", (0.0, 0.0, 1.11), (0.14, 0.097, 0.15)),
        _Part("chest", "ellipsoid", (0.0, 0.0, 1.29), (0.16, 0.105, 0.16)),
        _Part("neck", "capsule", (0.0, 0.005, 1.42), (0.0, 0.005, 1.58), 0.052, 0.048),
        _Part("head", "ellipsoid", (0.0, -0.012, 1.685), (0.083, 0.098, 0.113)),
    ]
    for s, sx in _SIDE.items():
        sh, el, wr = jp[f"shoulder_{s}"], jp[f"elbow_{s}"], jp[f"wrist_{s}"]
        d = (wr - el) / np.linalg.norm(wr - el)
        hand_c = wr + d * 0.085
        P += [
            _Part(f"clavicle_{s}", "capsule", (0.04 * sx, 0.0, 1.415), tuple(sh + np.array([0, 0, -0.005])), 0.05,
                  0.052),
            _Part(f"shoulder_{s}", "capsule", tuple(sh), tuple(el), 0.05, 0.038),
            _Part(f"elbow_{s}", "capsule", tuple(el), tuple(wr), 0.037, 0.027),
            _Part(f"wrist_{s}", "capsule", tuple(wr + d * 0.03), tuple(hand_c + d * 0.03), 0.034, 0.03),
        ]
        hp, kn, an, to = jp[f"hip_{s}"], jp[f"knee_{s}"], jp[f"ankle_{s}"], jp[f"toe_{s}"]
        P += [
            _Part(f"hip_{s}", "capsule", tuple(hp + np.array([0, 0, 0.02])), tuple(kn), 0.083, 0.052),
            _Part(f"knee_{s}", "capsule", tuple(kn), tuple(an), 0.05, 0.034),
            _Part(f"ankle_{s}", "capsule", tuple(an + np.array([0, 0.035, -0.06])), tuple(to + np.array([0, 0.0, 0.0])),
                  0.04, 0.036),
            _Part(f"toe_{s}", "capsule", tuple(to), tuple(to + np.array([0, -0.06, -0.002])), 0.034, 0.028),
        ]
    return P


_FAR = 1.0  # stand-in distance for parts farther than _CULL from a point (their blend weight is < 1e-3)
_CULL = 0.15


def _part_bounds(parts: list[_Part]) -> np.ndarray:
    """``(P, 2, 3)`` axis-aligned boxes of the parts."""
    out = np.empty((len(parts), 2, 3))
    for i, part in enumerate(parts):
        a, b = np.asarray(part.a), np.asarray(part.b)
        if part.kind == "capsule":
            r = max(part.ra, part.rb)
            out[i] = [np.minimum(a, b) - r, np.maximum(a, b) + r]
        else:
            out[i] = [a - b, a + b]
    return out


def _part_distances(parts: list[_Part], p: np.ndarray, cull: bool = False) -> np.ndarray:
    """Distance-like functions ``(P, N)`` of the parts at points ``p (N, 3)`` (negative inside).

    With ``cull`` a part is only evaluated within ``_CULL`` of its bounding box (``_FAR`` elsewhere).
    """
    out = np.full((len(parts), p.shape[0]), _FAR)
    bounds = _part_bounds(parts)
    for i, part in enumerate(parts):
        if cull:
            sel = np.nonzero(np.all((p >= bounds[i, 0] - _CULL) & (p <= bounds[i, 1] + _CULL), axis=1))[0]
            q = p[sel]
        else:
            sel, q = slice(None), p
        a = np.asarray(part.a)
        b = np.asarray(part.b)
        if part.kind == "capsule":
            ab = b - a
            t = np.clip(((q - a) * ab).sum(axis=1) / (ab * ab).sum(), 0.0, 1.0)  # no BLAS: the same mesh everywhere
            dv = q - (a + t[:, None] * ab)
            out[i, sel] = np.sqrt(np.einsum("ij,ij->i", dv, dv)) - (part.ra + t * (part.rb - part.ra))
        else:
            u = (q - a) / b
            k0 = np.sqrt(np.einsum("ij,ij->i", u, u))
            w = u / b
            k1 = np.sqrt(np.einsum("ij,ij->i", w, w))
            out[i, sel] = np.where(k1 > 1e-12, k0 * (k0 - 1.0) / np.maximum(k1, 1e-12), -b.min())
    return out


def _smooth_union(d: np.ndarray, k: float = BLEND) -> np.ndarray:
    m = d.min(axis=0)
    return m - k * np.log(np.exp(-(d - m) / k).sum(axis=0))


def _sdf(parts: list[_Part], p: np.ndarray, chunk: int = 65536) -> np.ndarray:
    out = np.empty(p.shape[0])
    for s in range(0, p.shape[0], chunk):
        out[s:s + chunk] = _smooth_union(_part_distances(parts, p[s:s + chunk], cull=True))
    return out


def _sdf_grad(parts: list[_Part], p: np.ndarray, eps: float = 1e-4) -> np.ndarray:
    """Central-difference gradient ``(N, 3)``."""
    g = np.empty_like(p)
    for c in range(3):
        e = np.zeros(3)
        e[c] = eps
        g[:, c] = (_sdf(parts, p + e) - _sdf(parts, p - e)) / (2 * eps)
    return g


def _project(parts: list[_Part], p: np.ndarray, steps: int = 3, eps: float = 1e-5) -> np.ndarray:
    """Newton steps onto the zero set (forward-difference gradients)."""
    for _ in range(steps):
        f0 = _sdf(parts, p)
        g = np.stack([(_sdf(parts, p + e) - f0) / eps for e in np.eye(3) * eps], axis=1)
        p = p - (f0 / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
    return p


def _adjacency(faces: np.ndarray, n: int):  # -> scipy.sparse.csr_matrix, row-normalised
    import scipy.sparse as sp

    i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]])
    j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]])
    a = sp.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    a.data[:] = 1.0
    deg = np.asarray(a.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(deg, 1)) @ a


def _check_closed_manifold(faces: np.ndarray, n_vertices: int) -> None:
    """Every directed edge once and its reverse once (closed, oriented 2-manifold), Euler characteristic 2."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = np.unique(e[:, 0] * n_vertices + e[:, 1])
    undirected, counts = np.unique(np.sort(e, axis=1) @ np.array([n_vertices, 1]), return_counts=True)
    ok = directed.size == e.shape[0] and bool(np.all(counts == 2))
    check(ok and n_vertices - undirected.size + faces.shape[0] == 2,
          "built-in character surface is not a closed genus-0 manifold (internal error)")


def _decimate(verts: np.ndarray, faces: np.ndarray, n_target: int) -> tuple[np.ndarray, np.ndarray]:
    """Topology-preserving decimation (VTK ``vtkDecimatePro`` via pyvista) down to ~``n_target`` vertices."""
    import pyvista as pv

    mesh = pv.PolyData(verts, np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
    out = mesh.decimate_pro(1.0 - n_target / verts.shape[0], preserve_topology=True)
    return np.asarray(out.points, dtype=np.float64), np.asarray(out.faces).reshape(-1, 4)[:, 1:].astype(np.int64)


def _relax(parts: list[_Part], verts: np.ndarray, faces: np.ndarray, rounds: int = 3) -> np.ndarray:
    """Tangential relaxation: Laplacian steps, each followed by re-projection onto the implicit surface."""
    lap = _adjacency(faces, verts.shape[0])
    verts = _project(parts, verts)
    for _ in range(rounds):
        verts = _project(parts, verts + 0.5 * (lap @ verts - verts), steps=2)
    return verts


def _mesh(density: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    parts = _parts()
    grid_density = max(density, MIN_GRID_DENSITY)
    h = GRID_SPACING / np.sqrt(grid_density)
    lo = np.array([-0.75, -0.25, -0.06])
    hi = np.array([0.75, 0.20, 1.86])
    n = np.ceil((hi - lo) / h).astype(int) + 1
    axes = [lo[c] + h * np.arange(n[c]) for c in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = _sdf(parts, grid).reshape(*n)
    verts, faces = surface_nets(values, lo, h)
    verts = _relax(parts, verts, faces)
    if density < grid_density:  # coarser than the grid can resolve (wrists, toes): decimate instead
        verts, faces = _decimate(verts, faces, int(round(verts.shape[0] * density / grid_density)))
        verts = _relax(parts, verts, faces)
        normals = vertex_normals(verts, faces).astype(np.float64)  # the coarse mesh departs from the surface
    else:
        g = _sdf_grad(parts, verts)
        normals = g / np.linalg.norm(g, axis=1, keepdims=True)  # exact normals of the smooth surface
    _check_closed_manifold(faces, verts.shape[0])
    return verts, faces, normals


def _skin_weights(verts: np.ndarray, faces: np.ndarray, parents: np.ndarray, density: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    parts = _parts()
    d = _part_distances(parts, verts)  # (P, V)
    part_joint = np.array([_IDX[p.joint] for p in parts])
    j = len(JOINT_NAMES)
    allowed = np.eye(j)
    for c, p in enumerate(parents):
        if p >= 0:
            allowed[c, p] = allowed[p, c] = 1.0
    score = np.exp(-(d - d.min(axis=0)) / SKIN_FALLOFF)  # (P, V)
    w = np.zeros((verts.shape[0], j))
    np.add.at(w.T, part_joint, score)
    # soft "neighbours of the nearest part's joint" mask: continuous where the nearest part changes
    near = np.exp(-(d - d.min(axis=0)) / (0.5 * SKIN_FALLOFF))  # (P, V)
    mask = small_matmul(near.T, allowed[part_joint]) / near.sum(axis=0)[:, None]  # (V, J), fixed order
    w *= mask
    lap = _adjacency(faces, verts.shape[0])
    for _ in range(int(round(12 * density)) + 2):  # ~ the same geometric smoothing radius at every density
        w = 0.5 * w + 0.5 * (lap @ w)
    w /= w.sum(1, keepdims=True)
    top = np.argsort(-w, axis=1, kind="stable")[:, :4]
    tw = np.take_along_axis(w, top, axis=1)
    tw /= tw.sum(1, keepdims=True)
    return top.astype(np.int64), tw.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# joint limits
_LIMITS_LEFT_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    # joint: ((a_x min, max), (a_y min, max), (a_z min, max)); R = R_bind R_x(a_x) R_z(a_z) R_y(a_y)
    "pelvis": ((0, 0), (0, 0), (0, 0)),
    "spine": ((-15, 40), (-20, 20), (-25, 25)),
    "chest": ((-15, 30), (-15, 15), (-20, 20)),
    "neck": ((-30, 40), (-20, 20), (-50, 50)),
    "head": ((-20, 25), (-15, 15), (-20, 20)),
    "clavicle": ((0, 0), (-25, 10), (-20, 15)),
    "shoulder": ((-100, 40), (-125, 31), (-45, 45)),  # a_y = -(elevation - 45): elevation 14..170 degrees
    "elbow": ((-140, 0), (0, 0), (0, 0)),
    "wrist": ((-60, 60), (-20, 30), (0, 0)),
    "hip": ((-110, 25), (-45, 15), (-30, 30)),
    "knee": ((0, 140), (0, 0), (0, 0)),
    "ankle": ((-20, 40), (-15, 15), (-15, 15)),
    "toe": ((-40, 20), (0, 0), (0, 0)),
}


def joint_limits_deg() -> np.ndarray:
    """``(J, 3, 2)`` joint limits in degrees (see the module docstring for the convention)."""
    lim = np.zeros((len(JOINT_NAMES), 3, 2))
    for i, name in enumerate(JOINT_NAMES):
        base, _, side = name.partition("_")
        l = np.array(_LIMITS_LEFT_DEG[base], dtype=np.float64)
        if side == "r":
            l[1:] = -l[1:, ::-1]
        lim[i] = l
    return lim


JOINT_LIMITS_DEG = joint_limits_deg()


# ---------------------------------------------------------------------------------------------
# motions: degrees-of-freedom curves -> local rotations
def _R(axis: tuple[float, float, float], deg: np.ndarray) -> np.ndarray:
    return axis_angle_matrix(np.asarray(axis, dtype=np.float64), np.radians(deg))


NEUTRAL = {"shoulder_elev": ARM_REST_ELEVATION, "elbow": 10.0, "knee": 2.0, "hip_flex": 1.0}


def _dof(d: dict[str, np.ndarray], key: str, n: int) -> np.ndarray:
    if key in d:
        return np.broadcast_to(np.asarray(d[key], dtype=np.float64), (n,))
    base = key[2:] if key[:2] in ("l_", "r_") else key
    return np.full(n, NEUTRAL.get(base, 0.0))


def _chain(*rots: np.ndarray) -> np.ndarray:
    """``R_1 @ R_2 @ ...`` of ``(n, 3, 3)`` rotation stacks, in fixed order (:func:`prt_torch.exact.small_matmul`)."""
    out = rots[0]
    for r in rots[1:]:
        out = small_matmul(out, r)
    return out


def _dofs_to_rotations(d: dict[str, np.ndarray], n: int) -> np.ndarray:
    """Local rotations ``(n, J, 3, 3)`` (parent frame, arm reference = hanging straight down) from DOF curves."""
    rot = np.tile(np.eye(3), (n, len(JOINT_NAMES), 1, 1))

    def g(k: str) -> np.ndarray:
        return _dof(d, k, n)

    X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    rot[:, _IDX["pelvis"]] = _chain(_R(Z, g("root_yaw")), _R(X, g("root_pitch")), _R(Y, g("root_roll")))
    for j in ("spine", "chest"):
        rot[:, _IDX[j]] = _chain(_R(Z, g(f"{j}_twist")), _R(X, g(f"{j}_flex")), _R(Y, g(f"{j}_side")))
    for j in ("neck", "head"):
        rot[:, _IDX[j]] = _chain(_R(Z, g(f"{j}_twist")), _R(X, g(f"{j}_flex")), _R(Y, g(f"{j}_side")))
    for s, sx in _SIDE.items():
        my = (0.0, -sx, 0.0)
        mz = (0.0, 0.0, -sx)
        rot[:, _IDX[f"clavicle_{s}"]] = _chain(_R(mz, g(f"{s}_clav_fwd")), _R(my, g(f"{s}_clav_up")))
        rot[:, _IDX[f"shoulder_{s}"]] = _chain(_R(mz, g(f"{s}_shoulder_horiz")), _R(X, -g(f"{s}_shoulder_flex")),
                                               _R(my, g(f"{s}_shoulder_elev")), _R(Z, sx * g(f"{s}_shoulder_twist")))
        rot[:, _IDX[f"elbow_{s}"]] = _R(X, -g(f"{s}_elbow"))
        rot[:, _IDX[f"wrist_{s}"]] = _R(X, -g(f"{s}_wrist"))
        rot[:, _IDX[f"hip_{s}"]] = _chain(_R(Z, sx * g(f"{s}_hip_twist")), _R(X, -g(f"{s}_hip_flex")),
                                          _R(my, g(f"{s}_hip_abd")))
        rot[:, _IDX[f"knee_{s}"]] = _R(X, g(f"{s}_knee"))
        rot[:, _IDX[f"ankle_{s}"]] = _R(X, -g(f"{s}_ankle"))
        rot[:, _IDX[f"toe_{s}"]] = _R(X, -g(f"{s}_toe"))
    return rot


def _ease(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _keyframes(t: np.ndarray, times: list[float], keys: list[dict[str, float]]) -> dict[str, np.ndarray]:
    """Smooth-step interpolation of DOF key poses (missing DOFs take their neutral value)."""
    names = sorted({k for key in keys for k in key})
    out: dict[str, np.ndarray] = {}
    for name in names:
        base = name[2:] if name[:2] in ("l_", "r_") else name
        vals = np.array([key.get(name, NEUTRAL.get(base, 0.0)) for key in keys])
        seg = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
        u = _ease((t - np.asarray(times)[seg]) / (np.asarray(times)[seg + 1] - np.asarray(times)[seg]))
        out[name] = vals[seg] + (vals[seg + 1] - vals[seg]) * u
    return out


def _both(d: dict[str, np.ndarray], key: str, left: np.ndarray, right: np.ndarray | None = None) -> None:
    d[f"l_{key}"] = left
    d[f"r_{key}"] = left if right is None else right


def _walk(t: np.ndarray) -> dict[str, np.ndarray]:
    ph = 2 * np.pi * t / 1.0
    d: dict[str, np.ndarray] = {}
    for s, sign in (("l", 1.0), ("r", -1.0)):
        p = ph + (0.0 if sign > 0 else np.pi)
        d[f"{s}_hip_flex"] = 4 + 24 * np.sin(p)
        d[f"{s}_knee"] = 5 + 55 * np.maximum(0.0, np.cos(p)) ** 2
        d[f"{s}_ankle"] = 6 * np.sin(p)
        d[f"{s}_shoulder_flex"] = -22 * np.sin(p)
        d[f"{s}_elbow"] = 18 + 14 * np.maximum(0.0, -np.sin(p))
    d["spine_twist"] = 5 * np.sin(ph)
    d["root_yaw"] = -4 * np.sin(ph)
    d["root_roll"] = 2 * np.sin(ph)
    d["chest_flex"] = np.full_like(t, 3.0)
    d["root_z"] = 0.012 * np.cos(2 * ph)
    return d


def _run(t: np.ndarray) -> dict[str, np.ndarray]:
    ph = 2 * np.pi * t / 0.8
    d: dict[str, np.ndarray] = {}
    for s, sign in (("l", 1.0), ("r", -1.0)):
        p = ph + (0.0 if sign > 0 else np.pi)
        d[f"{s}_hip_flex"] = 18 + 40 * np.sin(p)
        d[f"{s}_knee"] = 15 + 85 * np.maximum(0.0, np.cos(p)) ** 2
        d[f"{s}_ankle"] = 12 * np.sin(p)
        d[f"{s}_shoulder_flex"] = 8 - 45 * np.sin(p)
        d[f"{s}_shoulder_elev"] = np.full_like(t, 18.0)
        d[f"{s}_elbow"] = 85 + 15 * np.sin(p)
    d["spine_flex"] = np.full_like(t, 8.0)
    d["chest_twist"] = 8 * np.sin(ph)
    d["root_yaw"] = -5 * np.sin(ph)
    d["root_z"] = 0.05 * np.abs(np.sin(ph))
    return d


def _jumping_jacks(t: np.ndarray) -> dict[str, np.ndarray]:
    ph = 2 * np.pi * t / 1.0
    u = 0.5 * (1 - np.cos(ph))
    d: dict[str, np.ndarray] = {}
    _both(d, "shoulder_elev", ARM_REST_ELEVATION + 150 * u)
    _both(d, "elbow", 10 + 15 * u)
    _both(d, "hip_abd", 1 + 18 * u)
    _both(d, "knee", 5 + 20 * np.abs(np.sin(ph)))
    _both(d, "hip_flex", 3 + 10 * np.abs(np.sin(ph)))
    d["root_z"] = 0.07 * np.abs(np.sin(ph))
    return d


def _squat(t: np.ndarray) -> dict[str, np.ndarray]:
    u = 0.5 * (1 - np.cos(2 * np.pi * t / 1.6))
    d: dict[str, np.ndarray] = {}
    _both(d, "hip_flex", 100 * u)
    _both(d, "knee", 2 + 120 * u)
    _both(d, "ankle", 22 * u)
    _both(d, "hip_abd", 4 + 8 * u)
    _both(d, "shoulder_flex", 85 * u)
    _both(d, "shoulder_elev", ARM_REST_ELEVATION - 6 * u)
    _both(d, "elbow", 10 + 10 * u)
    d["spine_flex"] = 22 * u
    d["chest_flex"] = 10 * u
    d["neck_flex"] = -15 * u
    return d


def _wave(t: np.ndarray) -> dict[str, np.ndarray]:
    up = _ease(t / 0.6) * (1 - _ease((t - 2.4) / 0.6))
    osc = np.sin(2 * np.pi * 1.6 * (t - 0.6)) * _ease((t - 0.5) / 0.3) * (1 - _ease((t - 2.2) / 0.3))
    d: dict[str, np.ndarray] = {
        "r_shoulder_elev": ARM_REST_ELEVATION + 110 * up,
        "r_shoulder_flex": 25 * up,
        "r_elbow": 10 + 60 * up + 25 * osc * up,
        "r_wrist": 20 * osc * up,
        "r_clav_up": 12 * up,
        "l_shoulder_flex": 10 * up,
        "l_elbow": 10 + 30 * up,
        "chest_side": 6 * up,
        "neck_twist": -15 * up,
        "head_flex": -8 * up,
    }
    return d


_STRETCH_TIMES = [0.0, 0.7, 1.4, 2.1, 2.8, 3.4, 4.0]
_STRETCH_KEYS: list[dict[str, float]] = [
    {},
    {"l_shoulder_elev": 170, "r_shoulder_elev": 170, "spine_flex": -8, "chest_flex": -6, "l_elbow": 5, "r_elbow": 5,
     "neck_flex": -15, "l_clav_up": 15, "r_clav_up": 15},
    {"l_shoulder_elev": 165, "r_shoulder_elev": 170, "spine_side": -22, "chest_side": -15, "neck_side": -10,
     "l_elbow": 10, "r_elbow": 5, "l_hip_abd": 8, "r_hip_abd": 4},
    {"root_pitch": 55, "spine_flex": 25, "chest_flex": 20, "l_hip_flex": 55, "r_hip_flex": 55,
     "l_shoulder_flex": 60, "r_shoulder_flex": 60, "l_shoulder_elev": 8, "r_shoulder_elev": 8, "neck_flex": 10,
     "l_knee": 8, "r_knee": 8},
    {"spine_twist": 25, "chest_twist": 20, "l_shoulder_elev": 90, "r_shoulder_elev": 90, "l_shoulder_horiz": 80,
     "r_shoulder_horiz": 80, "l_elbow": 35, "r_elbow": 25, "neck_twist": 20},
    {"l_hip_flex": 95, "l_knee": 100, "l_ankle": -10, "r_knee": 8, "l_shoulder_elev": 60, "r_shoulder_elev": 60,
     "l_elbow": 60, "r_elbow": 60, "l_shoulder_flex": 30, "r_shoulder_flex": 30, "spine_flex": 10},
    {},
]


def _stretch(t: np.ndarray) -> dict[str, np.ndarray]:
    return _keyframes(t, _STRETCH_TIMES, _STRETCH_KEYS)


MOTIONS: dict[str, tuple[float, Callable[[np.ndarray], dict[str, np.ndarray]]]] = {
    "walk": (2.0, _walk),
    "run": (1.6, _run),
    "jumping_jacks": (2.0, _jumping_jacks),
    "squat": (3.2, _squat),
    "wave": (3.0, _wave),
    "stretch": (4.0, _stretch),
}


def _ground(rot: np.ndarray, root_z: np.ndarray, parents: np.ndarray, bind_local: np.ndarray) -> np.ndarray:
    """Root translations ``(n, 3)`` keeping the feet planted (see the module docstring)."""
    n = rot.shape[0]
    local = np.tile(bind_local, (n, 1, 1, 1))
    local[..., :3, :3] = rot
    world = forward_kinematics(parents, local)
    bind_world = forward_kinematics(parents, bind_local[None])[0]
    feet = [_IDX[f"{j}_{s}"] for j in ("ankle", "toe") for s in _SIDE]
    dz = (world[:, feet, 2, 3] - bind_world[feet, 2, 3]).min(axis=1)
    ankles = [_IDX["ankle_l"], _IDX["ankle_r"]]
    dxy = world[:, ankles][..., :2, 3].mean(axis=1) - bind_world[ankles][..., :2, 3].mean(axis=0)
    trans = np.tile(bind_local[0, :3, 3], (n, 1))
    trans[:, :2] -= dxy
    trans[:, 2] += root_z - dz
    return trans


def make_clip(name: str, bind_local: np.ndarray, parents: np.ndarray, fps: float = FPS) -> Clip:
    """One of the built-in motions (``CLIP_NAMES``) sampled at ``fps``."""
    check(name in MOTIONS, f"unknown built-in motion {name!r}; available: {list(MOTIONS)}")
    duration, fn = MOTIONS[name]
    t = np.arange(int(round(duration * fps)) + 1) / fps
    d = fn(t)
    n = t.size
    rot = _dofs_to_rotations(d, n)
    trans = np.tile(bind_local[:, :3, 3], (n, 1, 1))
    trans[:, 0] = _ground(rot, _dof(d, "root_z", n), parents, bind_local)
    return Clip.from_rotations(name, fps, rot, trans)


@functools.lru_cache(maxsize=4)
def _build(density: float) -> tuple[np.ndarray, ...]:
    table = _joint_table()
    parents = np.array([-1 if p is None else _IDX[p] for _, p, _ in table], dtype=np.int64)
    pos = np.array([p for _, _, p in table])
    verts, faces, normals = _mesh(density)
    dz = -verts[:, 2].min()  # stand on z = 0
    verts[:, 2] += dz
    pos[:, 2] += dz
    bw_rot = _bind_world_rotations()
    bind_world = np.tile(np.eye(4), (len(table), 1, 1))
    bind_world[:, :3, :3] = bw_rot
    bind_world[:, :3, 3] = pos
    bind_local = bind_world.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            bind_local[j] = small_matmul(rigid_inverse(bind_world[p]), bind_world[j])
    inverse_bind = rigid_inverse(bind_world)  # closed form (no LAPACK): the character is the same on every machine
    joints, weights = _skin_weights(verts - np.array([0, 0, dz]), faces, parents, density)
    return parents, bind_local, inverse_bind, verts.astype(np.float32), normals.astype(np.float32), faces, joints, \
        weights


def make_character(density: float = 1.0, fps: float = FPS) -> Character:
    """The built-in humanoid (deterministic) with the clips ``CLIP_NAMES`` sampled at ``fps``.

    ``density`` scales the vertex count (1.0 -> ~11-12k vertices, 0.25 -> ~3k). The geometry is
    cached per density; every call returns fresh arrays.
    """
    check(bool(np.isfinite(density)) and 0.02 <= density <= 16, f"density must be in [0.02, 16], got {density}")
    parents, bind_local, inverse_bind, verts, normals, faces, joints, weights = (
        a.copy() for a in _build(float(density)))
    clips = {n: make_clip(n, bind_local, parents, fps) for n in CLIP_NAMES}
    return Character(NAME, list(JOINT_NAMES), parents, bind_local, inverse_bind, verts, normals, faces, joints,
                     weights, clips, np.radians(JOINT_LIMITS_DEG))
