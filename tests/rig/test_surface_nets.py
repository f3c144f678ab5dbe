"""Surface nets against closed-form surfaces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from prt_torch.errors import PrtError
from prt_torch.rig.surface_nets import surface_nets


def grid(h: float, lo: float = -1.3, hi: float = 1.3) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(lo, hi + 1e-9, h)
    return np.stack(np.meshgrid(x, x, x, indexing="ij"), -1), np.full(3, x[0])


def test_sphere() -> None:
    p, origin = grid(0.05)
    v, f = surface_nets(np.linalg.norm(p, axis=-1) - 1.0, origin, 0.05)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2
    assert m.volume == pytest.approx(4 / 3 * np.pi, rel=0.01)  # positive: outward orientation
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.05 / 2


def test_torus_genus_one() -> None:
    p, origin = grid(0.04)
    r = np.hypot(p[..., 0], p[..., 1])
    v, f = surface_nets(np.hypot(r - 0.8, p[..., 2]) - 0.3, origin, 0.04)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.euler_number == 0
    assert m.volume == pytest.approx(2 * np.pi**2 * 0.8 * 0.3**2, rel=0.02)


def test_boundary_must_be_outside() -> None:
    p, origin = grid(0.1)
    with pytest.raises(PrtError, match="positive on the grid boundary"):
        surface_nets(np.linalg.norm(p, axis=-1) - 2.0, origin, 0.1)
