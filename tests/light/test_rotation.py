"""rotate_lighting vs closed forms: a rotated directional light comes from R d; the map's L2 norm is kept."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.light.envmap import EnvMap, envmap_to_sh, latlong_directions
from prt_torch.light.rotation import rotate_lighting
from prt_torch.light.sources import directional_light_sh
from prt_torch.sh.quadrature import random_rotations


def test_rotated_directional_light() -> None:
    d = np.array([0.2, -0.4, 0.9])
    d /= np.linalg.norm(d)
    for R in random_rotations(5, seed=0):
        a = rotate_lighting(directional_light_sh(d, [1.0, 2.0, 3.0], 6, half_angle=0.2), R)
        b = directional_light_sh(R @ d, [1.0, 2.0, 3.0], 6, half_angle=0.2)
        np.testing.assert_allclose(a, b, atol=1e-10)


def test_rotating_the_map_commutes_with_projection() -> None:
    # a band-limited map rendered in rotated coordinates projects to the rotated coefficients
    rng = np.random.default_rng(2)
    sh = rng.normal(size=(9, 3))
    R = random_rotations(1, seed=4)[0]
    dirs = latlong_directions(128, 256)
    from prt_torch.sh.basis import sh_basis

    rotated_img = sh_basis(dirs @ R, 3) @ sh  # L(R^T w)
    got = envmap_to_sh(EnvMap(rotated_img.astype(np.float32), "latlong"), 3)
    np.testing.assert_allclose(got, rotate_lighting(sh, R), atol=2e-3 * np.abs(sh).max())


def test_bad_inputs() -> None:
    sh = np.zeros((9, 3))
    with pytest.raises(PrtError, match="proper rotation"):
        rotate_lighting(sh, np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(PrtError, match=r"\(3, 3\)"):
        rotate_lighting(sh, np.eye(4))
    with pytest.raises(PrtError, match=r"\(C, 3\)"):
        rotate_lighting(np.zeros(9), np.eye(3))
    with pytest.raises(PrtError, match="square"):
        rotate_lighting(np.zeros((8, 3)), np.eye(3))
    with pytest.raises(PrtError, match="NaN"):
        rotate_lighting(np.full((9, 3), np.nan), np.eye(3))
