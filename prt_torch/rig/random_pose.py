"""Random training poses (seed 003 sec. 5.1: "regularly sampling the space of input parameters").

* Characters with ``joint_limits (J, 3, 2)`` (the built-in humanoid): every joint's bind-relative
  angles ``(a_x, a_y, a_z)`` are drawn independently and uniformly within the limits and composed
  as ``R_bind @ R_x(a_x) @ R_z(a_z) @ R_y(a_y)``; joint translations and the root stay at the bind
  pose. Independent sampling can produce self-intersecting poses (e.g. an arm through the torso);
  that is accepted (visibility is still well defined).
* Characters without limits (glTF/BVH): each random pose starts from a random frame of a random
  clip and every non-root joint's rotation is perturbed by a random rotation of angle up to
  ``perturb_deg`` about a uniformly random axis; the root keeps its bind transform.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip
from prt_torch.rig.rotations import axis_angle_matrix


def _axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    e = np.zeros(3)
    e[axis] = 1.0
    return axis_angle_matrix(e, angles)


def compose_limit_angles(angles: np.ndarray) -> np.ndarray:
    """``R_x(a_x) @ R_z(a_z) @ R_y(a_y)`` for angles ``(..., 3)`` = ``(a_x, a_y, a_z)`` radians -> ``(..., 3, 3)``."""
    angles = np.asarray(angles, dtype=np.float64)
    return _axis_rotations(0, angles[..., 0]) @ _axis_rotations(2, angles[..., 2]) @ _axis_rotations(1, angles[..., 1])


def random_poses(character: Character, n: int, seed: int = 0, perturb_deg: float = 20.0,
                 name: str = "random", fps: float = 30.0) -> Clip:
    """``n`` random poses of ``character`` as a :class:`Clip` (independent frames); deterministic in ``seed``."""
    check(isinstance(n, int | np.integer) and n >= 1, f"number of random poses must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    j = character.num_joints
    local = np.tile(character.bind_local, (n, 1, 1, 1))
    nonroot = character.parents >= 0
    if character.joint_limits is not None:
        lim = character.joint_limits
        u = rng.random((n, j, 3))
        angles = lim[None, :, :, 0] + u * (lim[None, :, :, 1] - lim[None, :, :, 0])
        rel = compose_limit_angles(angles)
        rot = character.bind_local[None, :, :3, :3] @ rel
        local[:, nonroot, :3, :3] = rot[:, nonroot]
        return Clip(name, fps, local)
    check(len(character.clips) > 0,
          f"character {character.name!r} has neither joint limits nor clips to sample random poses from")
    clips = [character.clips[k] for k in sorted(character.clips)]
    ci = rng.integers(0, len(clips), size=n)
    src = np.stack([clips[c].local[rng.integers(0, clips[c].num_frames)] for c in ci])  # (n, J, 4, 4)
    axis = rng.normal(size=(n, j, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    ang = np.radians(perturb_deg) * np.cbrt(rng.random((n, j)))
    k = np.zeros((n, j, 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(ang)[..., None, None], np.cos(ang)[..., None, None]
    pert = np.eye(3) + s * k + (1 - c) * (k @ k)
    local[:, nonroot] = src[:, nonroot]
    local[:, nonroot, :3, :3] = src[:, nonroot, :3, :3] @ pert[:, nonroot]
    return Clip(name, fps, local)
