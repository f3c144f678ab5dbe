"""Forward kinematics of a joint hierarchy (numpy, batched over frames).

A skeleton is ``parents (J,)`` int64 with ``-1`` for roots and ``parents[j] < j`` (topological order).
Local transforms ``(F, J, 4, 4)`` map a joint's frame into its parent's frame (roots: into the z-up
world); world transforms are their products along the chain.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.exact import small_matmul
from prt_torch.shapes import check_shape


def check_parents(parents: np.ndarray) -> np.ndarray:
    """Validate ``parents (J,)``: integers, ``-1`` for roots, ``parents[j] < j``; returns it as int64."""
    parents = np.asarray(parents)
    check_shape(parents, "J", name="parents")
    check(parents.size > 0, f"parents must be a non-empty (J,) array, got shape {parents.shape}")
    check(np.issubdtype(parents.dtype, np.integer), f"parents must be integers, got {parents.dtype}")
    parents = parents.astype(np.int64)
    idx = np.arange(parents.size)
    check(bool(np.all((parents >= -1) & (parents < idx))),
          "parents must satisfy -1 <= parents[j] < j (joints in topological order)")
    return parents


def forward_kinematics(parents: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World transforms ``(..., J, 4, 4)`` from local transforms ``(..., J, 4, 4)``.

    ``world[j] = world[parents[j]] @ local[j]``; roots: ``world[j] = local[j]``. The loop runs over
    joints (tens), vectorised over frames.
    """
    local = np.asarray(local, dtype=np.float64)
    check_shape(local, ("*", len(parents), 4, 4), name="local transforms")
    world = np.empty_like(local)
    for j, p in enumerate(parents):
        # fixed-order 4x4 products: FK feeds the bake, which is bit-exact across machines (prt_torch.exact)
        world[..., j, :, :] = local[..., j, :, :] if p < 0 else small_matmul(world[..., p, :, :], local[..., j, :, :])
    return world


def world_to_local(parents: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Inverse of :func:`forward_kinematics`: local ``(..., J, 4, 4)`` from world ``(..., J, 4, 4)``."""
    world = np.asarray(world, dtype=np.float64)
    local = world.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            local[..., j, :, :] = np.linalg.solve(world[..., p, :, :], world[..., j, :, :])
    return local
