"""ZH lobes rotated into vertex frames vs full SH rotation matrices (prt_torch.sh.rotation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.quadrature import random_rotations
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import lobes_to_sh
from prt_torch.shade.lobes import rotate_lobes_to_frames


def _lobes(k: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(k, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True), rng.normal(size=(k, n, 3))


def test_matches_sh_rotation_of_world_lighting() -> None:
    n = 5
    dirs, coeffs = _lobes(3, n, 0)
    world = lobes_to_sh(dirs, coeffs)  # (C, 3)
    F = random_rotations(12, seed=1).reshape(2, 6, 3, 3)  # (B, V, 3, 3) frames, rows (t, b, n)
    got = rotate_lobes_to_frames(torch.from_numpy(dirs), torch.from_numpy(coeffs), torch.from_numpy(F))
    assert got.shape == (2, 6, n * n, 3)
    # local lighting L_loc(w) = L(F^T w): coefficients D(F) @ l (sh_rotation convention)
    ref = np.einsum("bvij,jc->bvic", sh_rotation(F, n), world)
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-10)


def test_identity_frame_and_float32() -> None:
    dirs, coeffs = _lobes(2, 3, 2)
    F = torch.eye(3).expand(4, 3, 3)
    got = rotate_lobes_to_frames(torch.from_numpy(dirs).float(), torch.from_numpy(coeffs).float(), F)
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got[0].numpy(), lobes_to_sh(dirs, coeffs), atol=1e-5)


def test_bad_inputs() -> None:
    dirs, coeffs = _lobes(2, 3, 2)
    d, c = torch.from_numpy(dirs), torch.from_numpy(coeffs)
    F = torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    with pytest.raises(PrtError, match=r"\(K, 3\)"):
        rotate_lobes_to_frames(d[:, :2], c, F)
    with pytest.raises(PrtError, match="unit"):
        rotate_lobes_to_frames(d * 2, c, F)
    with pytest.raises(PrtError, match="lobe_coeffs must have shape"):
        rotate_lobes_to_frames(d, c[:1], F)
    with pytest.raises(PrtError, match="orthonormal"):
        rotate_lobes_to_frames(d, c, F * 2)
    with pytest.raises(PrtError, match=r"\(\.\.\., V, 3, 3\)"):
        rotate_lobes_to_frames(d, c, torch.zeros(4, 3))
    with pytest.raises(PrtError, match="unsupported SH order"):
        rotate_lobes_to_frames(d, torch.zeros(2, 0, 3, dtype=torch.float64), F)
