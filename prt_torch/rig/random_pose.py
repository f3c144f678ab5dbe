"""Random training poses (seed 003 sec. 5.1: "regularly sampling the space of input parameters").

Two modes (``random_poses(..., mode=...)``), both deterministic in ``seed``:

``"uniform"`` (the default, the original sampler) moves EVERY joint at once:

* Characters with ``joint_limits (J, 3, 2)`` (the built-in humanoid): every joint's bind-relative
  angles ``(a_x, a_y, a_z)`` are drawn independently and uniformly within the limits and composed
  as ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)``; joint translations and the root stay at the bind
  pose. Independent sampling can produce self-intersecting poses (e.g. an arm through the torso);
  that is accepted (visibility is still well defined).
* Characters without limits (glTF/BVH): each random pose starts from a uniformly random frame of a
  uniformly random clip of ``base_clips`` (the source clips the caller passes: TRAINING clips or
  training frame ranges only, never the character's other clips) and every non-root joint's rotation
  is perturbed by a random rotation of angle up to ``perturb_deg`` about a uniformly random axis; the
  root keeps its bind transform. Without source clips this is an error.

``"sparse"`` moves only a FEW joint chains per pose, so that every limb's configuration space is
covered without teaching a cluster correlations with far-away limbs that real motion never has:

* The skeleton is split into chains (:func:`joint_chains`): maximal runs of joints below the root or
  a branching joint, each joint having at most one child (humanoid: spine, neck+head, each arm from
  the clavicle, each leg from the hip).
* Each key pose starts from a base pose, the bind pose or (with probability ``base_clip_prob``) a
  uniformly random frame of one of ``base_clips`` (the caller passes TRAINING clips only; the root
  and every joint outside the chosen chains keep the base frame's transforms), then ``1..max_chains``
  distinct chains (uniform count, uniform choice) get new rotations: uniform within the joint limits
  (as in ``"uniform"``; with probability ``near_base`` per joint, a uniform fraction of the way from
  the base's angles to that sample, to concentrate poses near plausible ones) or, without limits,
  the base rotation times a random rotation of angle up to ``perturb_deg``.
* ``segment > 1`` turns the key poses into continuous trajectories: consecutive key poses are joined
  by ``segment`` frames of per-joint geodesic (slerp) rotation and linear translation interpolation,
  so CV folds blocked by contiguous frame ranges hold out whole motions. ``segment = 1`` gives
  independent poses.

No mode samples from ``character.clips`` on its own: every clip frame a random pose derives from
comes from ``base_clips`` (``Clip`` objects, or names looked up in ``character.clips``), so held-out
motion cannot leak into training (the bake plan,
:func:`prt_torch.bake.plan.make_plan`, is the one place that builds these sources from the split).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from prt_torch.errors import check
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.rotations import axis_angle_matrix

MODES = ("uniform", "sparse")


def _axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    e = np.zeros(3)
    e[axis] = 1.0
    return axis_angle_matrix(e, angles)


def compose_limit_angles(angles: np.ndarray) -> np.ndarray:
    """``R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` for angles ``(..., 3)`` = ``(a_x, a_y, a_z)`` radians -> ``(..., 3, 3)``."""
    angles = np.asarray(angles, dtype=np.float64)
    return _axis_rotations(0, angles[..., 0]) @ _axis_rotations(2, angles[..., 2]) @ _axis_rotations(1, angles[..., 1])


def joint_chains(parents: np.ndarray) -> list[list[int]]:
    """Split a skeleton ``parents (J,)`` (``-1`` = root) into chains of non-root joints.

    A chain starts at a child of a root or of a branching joint (two or more children) and follows
    single children until a leaf or a branching joint (which is included and ends the chain). Every
    non-root joint is in exactly one chain; chains are ordered by their first joint.
    """
    parents = np.asarray(parents)
    children: list[list[int]] = [[] for _ in range(parents.shape[0])]
    for c, p in enumerate(parents):
        if p >= 0:
            children[int(p)].append(c)
    starts = [c for c, p in enumerate(parents) if p >= 0 and (parents[p] < 0 or len(children[int(p)]) != 1)]
    chains = []
    for s in starts:
        chain = [s]
        while len(children[chain[-1]]) == 1:
            chain.append(children[chain[-1]][0])
        chains.append(chain)
    return chains


def _random_rotations(rng: np.random.Generator, shape: tuple[int, ...], max_deg: float) -> np.ndarray:
    """Rotations ``shape + (3, 3)`` about uniform axes by angles up to ``max_deg`` (uniform in the ball)."""
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    ang = np.radians(max_deg) * np.cbrt(rng.random(shape))
    k = np.zeros(shape + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(ang)[..., None, None], np.cos(ang)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def limit_angles(character: Character, local: np.ndarray) -> np.ndarray:
    """Bind-relative angles ``(..., J, 3)`` = ``(a_x, a_y, a_z)`` radians of local transforms ``(..., J, 4, 4)``.

    The inverse of ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` (intrinsic X-Z-Y Euler angles, scipy).
    """
    rel = np.swapaxes(character.bind_local[..., :3, :3], -1, -2) @ local[..., :3, :3]
    xzy = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_euler("XZY").reshape(*rel.shape[:-2], 3)
    return xzy[..., [0, 2, 1]]


def _limit_rotations(character: Character, rng: np.random.Generator, n: int, base: np.ndarray | None = None,
                     near_base: float = 0.0) -> np.ndarray:
    """``(n, J, 3, 3)`` local rotations uniform within the joint limits (``R_bind @ R(angles)``).

    With ``base (n, J, 4, 4)`` and ``near_base > 0``: with probability ``near_base`` per (pose, joint)
    the angles are ``base + f * (uniform - base)`` with ``f ~ U(0, 1)`` (between the base and a uniform
    sample: concentrated near the base, within the limits whenever the base is).
    """
    lim = character.joint_limits
    u = rng.random((n, character.num_joints, 3))
    angles = lim[None, :, :, 0] + u * (lim[None, :, :, 1] - lim[None, :, :, 0])
    if base is not None and near_base > 0:
        near = rng.random((n, character.num_joints)) < near_base
        f = np.where(near, rng.random((n, character.num_joints)), 1.0)[..., None]
        b = limit_angles(character, base)
        angles = b + f * (angles - b)
    return character.bind_local[None, :, :3, :3] @ compose_limit_angles(angles)


def _interpolate(keys: np.ndarray, segment: int, n: int) -> np.ndarray:
    """``n`` frames joining key poses ``keys (K, J, 4, 4)``, ``segment`` frames per key-to-key step.

    Rotations: per-joint slerp; translations: linear. Frame ``i * segment`` is key ``i`` exactly.
    """
    k, j = keys.shape[:2]
    idx = np.arange(n)
    seg = np.minimum(idx // segment, k - 2)
    t = (idx - seg * segment) / segment  # (n,) in [0, 1]
    a, b = keys[seg], keys[seg + 1]  # (n, J, 4, 4)
    rel = np.swapaxes(a[..., :3, :3], -1, -2) @ b[..., :3, :3]
    rv = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(n, j, 3)
    step = Rotation.from_rotvec((rv * t[:, None, None]).reshape(-1, 3)).as_matrix().reshape(n, j, 3, 3)
    out = a.copy()
    out[..., :3, :3] = a[..., :3, :3] @ step
    out[..., :3, 3] = a[..., :3, 3] + t[:, None, None] * (b[..., :3, 3] - a[..., :3, 3])
    return out


def _sparse_poses(character: Character, n: int, rng: np.random.Generator, perturb_deg: float,
                  base_clips: Sequence[Clip], base_clip_prob: float, max_chains: int, segment: int,
                  near_base: float) -> np.ndarray:
    """Local transforms ``(n, J, 4, 4)`` of the ``"sparse"`` mode (see the module docstring)."""
    j = character.num_joints
    chains = joint_chains(character.parents)
    check(len(chains) > 0, f"character {character.name!r} has no non-root joints to pose")
    n_keys = n if segment == 1 else -(-(n - 1) // segment) + 1
    # base poses
    base = np.tile(character.bind_local, (n_keys, 1, 1, 1))
    if base_clips and base_clip_prob > 0:
        use = rng.random(n_keys) < base_clip_prob
        ci = rng.integers(0, len(base_clips), size=n_keys)
        fi = np.floor(rng.random(n_keys) * np.array([base_clips[c].num_frames for c in ci])).astype(np.int64)
        for k in np.nonzero(use)[0]:
            base[k] = base_clips[ci[k]].local[fi[k]]
    # which chains move: a uniform count in 1..max_chains, then a uniform subset of that size
    m = min(max_chains, len(chains))
    count = rng.integers(1, m + 1, size=n_keys)
    order = np.argsort(rng.random((n_keys, len(chains))), axis=1)
    chosen_chain = np.zeros((n_keys, len(chains)), dtype=bool)
    np.put_along_axis(chosen_chain, order, np.arange(len(chains))[None, :] < count[:, None], axis=1)
    joint_chain = np.full(j, -1)
    for c, chain in enumerate(chains):
        joint_chain[chain] = c
    moved = np.zeros((n_keys, j), dtype=bool)
    nonroot = joint_chain >= 0
    moved[:, nonroot] = chosen_chain[:, joint_chain[nonroot]]
    # new rotations for the moved joints
    if character.joint_limits is not None:
        new = _limit_rotations(character, rng, n_keys, base if near_base > 0 else None, near_base)
    else:
        new = base[..., :3, :3] @ _random_rotations(rng, (n_keys, j), perturb_deg)
    keys = base.copy()
    keys[..., :3, :3] = np.where(moved[..., None, None], new, base[..., :3, :3])
    return keys if segment == 1 else _interpolate(keys, segment, n)


def random_poses(character: Character, n: int, seed: int = 0, perturb_deg: float = 20.0,
                 name: str = "random", fps: float = 30.0, mode: str = "uniform",
                 base_clips: Sequence[str | Clip] = (), base_clip_prob: float = 0.5, max_chains: int = 3,
                 segment: int = 1, near_base: float = 0.0) -> Clip:
    """``n`` random poses of ``character`` as a :class:`Clip` with ``local (n, J, 4, 4)``; deterministic in ``seed``.

    ``base_clips`` are the SOURCE clips of every mode (names of the character's clips or :class:`Clip`
    objects, e.g. a training frame range of a clip; pass training motion only): the only clip frames a
    random pose may start from. Nothing else of the character's clips is ever read.

    ``mode="uniform"``: independent frames moving every joint: within the joint limits (``base_clips``
    unused), or, without limits, a random frame of ``base_clips`` with every non-root joint perturbed by
    up to ``perturb_deg`` degrees (no source clip: :class:`PrtError`).
    ``mode="sparse"``: each key pose moves ``1..max_chains`` joint chains of a base pose (the bind
    pose or, with probability ``base_clip_prob``, a random frame of ``base_clips``), key poses joined by
    ``segment`` interpolated frames (``1``: independent poses); ``near_base``: the probability that a
    moved joint lands between its base angles and the uniform sample (joint limits only). See the
    module docstring.
    """
    check(isinstance(n, int | np.integer) and n >= 1, f"number of random poses must be >= 1, got {n}")
    check(mode in MODES, f"unknown random pose mode {mode!r}; expected one of {list(MODES)}")
    check(isinstance(segment, int | np.integer) and segment >= 1, f"random pose segment must be >= 1, got {segment}")
    check(isinstance(max_chains, int | np.integer) and max_chains >= 1,
          f"random pose max_chains must be >= 1, got {max_chains}")
    check(0.0 <= base_clip_prob <= 1.0, f"random pose base_clip_prob must be in [0, 1], got {base_clip_prob}")
    check(0.0 <= near_base <= 1.0, f"random pose near_base must be in [0, 1], got {near_base}")
    check(np.isfinite(perturb_deg) and perturb_deg >= 0, f"perturb_deg must be finite and >= 0, got {perturb_deg}")
    check(isinstance(base_clips, Sequence) and not isinstance(base_clips, str),
          f"random pose base_clips must be a sequence of clip names or Clips, got {type(base_clips).__name__}")
    clips = [character.clip(c) for c in base_clips]  # unknown names / wrong joint counts: PrtError
    rng = np.random.default_rng(seed)
    j = character.num_joints
    if mode == "sparse":
        check(character.joint_limits is not None or len(clips) > 0 or perturb_deg > 0,
              "sparse random poses need joint limits, base clips or perturb_deg > 0")
        return Clip(name, fps, _sparse_poses(character, n, rng, perturb_deg, clips, base_clip_prob, max_chains,
                                             segment, near_base))
    local = np.tile(character.bind_local, (n, 1, 1, 1))
    nonroot = character.parents >= 0
    if character.joint_limits is not None:
        rot = _limit_rotations(character, rng, n)
        local[:, nonroot, :3, :3] = rot[:, nonroot]
        return Clip(name, fps, local)
    check(len(clips) > 0, f"character {character.name!r} has no joint limits and no training clip to sample "
                          "random poses from (base_clips is empty)")
    ci = rng.integers(0, len(clips), size=n)
    src = np.stack([clips[c].local[rng.integers(0, clips[c].num_frames)] for c in ci])  # (n, J, 4, 4)
    pert = _random_rotations(rng, (n, j), perturb_deg)
    local[:, nonroot] = src[:, nonroot]
    local[:, nonroot, :3, :3] = src[:, nonroot, :3, :3] @ pert[:, nonroot]
    return Clip(name, fps, local)
