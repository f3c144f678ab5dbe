"""Ground shadow under a single sphere vs the closed form: the floor's visibility (SHEXP of the spheres at the ground
vertices, in the ground frame) against the exact spherical cap (closed-form ZH), and the diffuse irradiance it
gives under a uniform sky against the sphere's form factor ``sin^2(a) cos(theta)``; plus spheres crossing the floor
(:func:`prt_torch.scene.scene.spheres_above`)."""

from __future__ import annotations

import numpy as np

from prt_torch.scene.compose import constant_one
from prt_torch.scene.ground import make_ground
from prt_torch.scene.scene import spheres_above
from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh
from tests.scene.refs import cap_sh, sphere_blocked_irradiance_fraction

ORDER = 4


def _ground_vis(g, centers, radii):
    from prt_torch.shexp import shexp_visibility

    v = shexp_visibility(g.vertices.copy(), centers, radii, ORDER, frames=g.frames().copy())
    return v.numpy().astype(np.float64)


def test_floor_under_one_sphere_is_the_cap_and_its_form_factor() -> None:
    c, r = np.array([0.2, -0.1, 1.0]), 0.35
    g = make_ground((0.0, 0.0), 3.0, 0.0, resolution=12)
    vis = _ground_vis(g, c[None].astype(np.float32), np.array([r], np.float32))
    d = c[None] - g.vertices.astype(np.float64)
    dist = np.linalg.norm(d, axis=1)
    blocked_exact = cap_sh(d / dist[:, None], np.arcsin(r / dist), ORDER)
    blocked = constant_one(ORDER) - vis
    # one sphere: SHEXP's order-4 log/exp round trip reproduces the cap to a few % (measured 3.3%: the log of a cap
    # truncated to order 4 does not exponentiate back to the truncated cap exactly)
    assert np.linalg.norm(blocked - blocked_exact) / np.linalg.norm(blocked_exact) < 0.05
    # diffuse irradiance under a uniform sky (radiance 1): E = v . A (the clamped cosine about the ground normal +z,
    # exact for the order-n part of v), unoccluded E = pi; the blocked fraction vs the closed-form form factor
    cos_sh = zh_to_sh(clamped_cosine_zh(ORDER), np.array([0.0, 0.0, 1.0]))
    frac = 1.0 - (vis @ cos_sh) / np.pi
    frac_cap4 = (blocked_exact @ cos_sh) / np.pi  # the exact cap truncated to order 4
    want = sphere_blocked_irradiance_fraction(g.vertices.astype(np.float64), c, r)
    # vs the order-4 exact cap: the SHEXP error alone
    assert np.abs(frac - frac_cap4).max() < 0.03 * want.max()  # measured 1.1%
    # vs the closed form: order-4 truncation too (the clamped cosine's bands >= 4, A_4 = -pi/24, are dropped; a
    # small cap has large high bands): stated tolerance 10% of the shadow's depth (measured 6%)
    assert np.abs(frac - want).max() < 0.10 * want.max()
    assert np.argmin(np.abs(g.vertices[:, :2] - c[:2]).sum(1)) == np.argmax(frac)  # darkest right under the sphere


def test_spheres_crossing_the_floor_keep_their_part_above_it() -> None:
    c = np.array([[[0.0, 0.0, 0.05], [1.0, 0.0, 1.0], [2.0, 0.0, -0.5]]], np.float32)
    r = np.array([[0.1, 0.2, 0.1]], np.float32)
    c2, r2 = spheres_above(c, r, 0.0)
    np.testing.assert_allclose(r2[0], [0.075, 0.2, 1e-6], rtol=1e-5)
    np.testing.assert_allclose(c2[0, :, 2], [0.075, 1.0, 1e-6], atol=1e-6)
    assert np.all(c2[..., 2] - r2 >= -1e-6)  # nothing below the floor
    np.testing.assert_allclose(c2[..., :2], c[..., :2])
