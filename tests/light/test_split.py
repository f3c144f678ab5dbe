"""The light split (issue 27, :mod:`prt_torch.sg.split`): peaks + residual against closed forms and quadrature.

The synthetic maps are rendered here from the documented lat-long convention (not from the library's mappings):
a smooth sky ``a + b z`` (pixel means exact: the mean of ``z`` over a lat-long pixel is ``(cos t0 + cos t1) / 2``)
plus uniform discs, each pixel's disc coverage by 8 x 8 solid-angle-weighted sub-samples. References: the disc's
power ``D 2 pi (1 - cos r)``, the sky's power ``4 pi a`` and its SH ``a sqrt(4 pi) e_0 + b sqrt(4 pi / 3) e_2``,
the procedural sky's integral by Gauss-Legendre quadrature of the CIE formula.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.light.envmap import EnvMap
from prt_torch.light.sources import cie_clear_sky
from prt_torch.sg.split import MAX_PEAKS, LightSplit, PeakLight, split_envmap, split_sky
from prt_torch.sh.basis import sh_basis

H = 256  # 256 x 512: 0.70 degree pixels
SKY_A = np.array([1.0, 1.2, 1.5])
SKY_B = np.array([0.5, 0.6, 0.9])
SUB = 8


def _dir(elev_deg: float, azim_deg: float) -> np.ndarray:
    e, a = math.radians(elev_deg), math.radians(azim_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def _pixel_omega(h: int) -> np.ndarray:
    """``(H, 2H)`` exact lat-long pixel solid angles ``(2 pi / W) (cos t0 - cos t1)``."""
    ct = np.cos(np.pi * np.arange(h + 1) / h)
    return np.repeat(((np.pi / h) * (ct[:-1] - ct[1:]))[:, None], 2 * h, axis=1)


def _coverage(h: int, center: np.ndarray, radius: float) -> np.ndarray:
    """``(H, 2H)`` solid-angle fraction of each pixel inside the cap ``(center, radius)``, rows near it only."""
    w = 2 * h
    theta_c = math.acos(center[2])
    band = np.flatnonzero((np.pi * (np.arange(h) + 1) / h >= theta_c - radius - 1e-9)
                          & (np.pi * np.arange(h) / h <= theta_c + radius + 1e-9))
    # sub-sample centres: theta, phi of the documented mapping (row 0 up, phi = pi/2 - 2 pi (u - 1/2))
    t_edges = np.pi * (band[:, None] + (np.arange(SUB) + 0.5)[None, :] / SUB) / h  # (R, SUB)
    u = (np.arange(w)[:, None] + (np.arange(SUB) + 0.5)[None, :] / SUB) / w  # (W, SUB)
    phi = np.pi / 2 - 2 * np.pi * (u - 0.5)
    st, ct = np.sin(t_edges), np.cos(t_edges)
    d = np.stack(np.broadcast_arrays(st[:, :, None, None] * np.cos(phi)[None, None], st[:, :, None, None]
                                     * np.sin(phi)[None, None], ct[:, :, None, None]), -1)  # (R, SUB, W, SUB, 3)
    inside = (d @ center) >= math.cos(radius)
    wt = np.sin(t_edges)[:, :, None, None] * np.ones((1, 1, w, SUB))  # sub-sample solid angle ~ sin(theta)
    cov = np.zeros((h, w))
    cov[band] = (inside * wt).sum((1, 3)) / wt.sum((1, 3))
    return cov


def _map(discs: list[tuple[np.ndarray, float, np.ndarray]], h: int = H) -> EnvMap:
    ct = np.cos(np.pi * np.arange(h + 1) / h)
    zmean = 0.5 * (ct[:-1] + ct[1:])
    img = np.broadcast_to((SKY_A + SKY_B * zmean[:, None])[:, None, :], (h, 2 * h, 3)).copy()
    for c, r, rad in discs:
        img += _coverage(h, c, r)[..., None] * rad
    return EnvMap(img.astype(np.float32), "latlong", "synthetic")


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, float(np.dot(a, b)))))


def _split_power(split: LightSplit) -> np.ndarray:
    """Peaks (closed-form disc integrals) + residual (exact pixel solid angles, computed here)."""
    peaks = sum((p.radiance * 2 * np.pi * (1 - math.cos(p.angular_radius)) for p in split.peaks), np.zeros(3))
    res = split.residual.image.astype(np.float64)
    return peaks + np.einsum("hw,hwc->c", _pixel_omega(res.shape[0]), res)


DISC_RAD = np.array([400.0, 300.0, 200.0])
DISC_R = math.radians(4.0)


@pytest.mark.parametrize("center", [_dir(35.0, 120.0), _dir(20.0, 270.0)], ids=["generic", "on the seam (-y)"])
def test_a_disc_light_is_found_at_its_direction_radius_and_radiance(center: np.ndarray) -> None:
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    env = _map([(center, DISC_R, DISC_RAD)])
    split = split_envmap(env)
    assert len(split.peaks) == 1, [p.to_dict() for p in split.peaks]
    p = split.peaks[0]
    pixel_deg = 180.0 / H
    assert _angle_deg(p.direction, center) < pixel_deg
    assert abs(math.degrees(p.angular_radius - DISC_R)) < max(0.5 * pixel_deg, 0.2 * math.degrees(DISC_R))
    np.testing.assert_allclose(p.radiance, DISC_RAD, rtol=0.05)
    # the disc's power (closed form) and the map's (the sky's 4 pi a plus it), each within 1 % per channel
    disc_power = DISC_RAD * 2 * np.pi * (1 - math.cos(DISC_R))
    np.testing.assert_allclose(p.power, disc_power, rtol=0.01)
    np.testing.assert_allclose(_split_power(split), 4 * np.pi * SKY_A + disc_power, rtol=0.01)
    map_power = np.einsum("hw,hwc->c", _pixel_omega(H), env.image.astype(np.float64))
    np.testing.assert_allclose(_split_power(split), map_power, rtol=0.01)
    # the residual is the sky again: its order-4 SH against the sky's closed form (a sqrt(4 pi), b sqrt(4 pi / 3))
    want = np.zeros((16, 3))
    want[0], want[2] = SKY_A * math.sqrt(4 * np.pi), SKY_B * math.sqrt(4 * np.pi / 3)
    got = split.residual.to_sh(4)
    assert np.abs(got - want).max() < 1e-3 * np.abs(want[0]).min(), np.abs(got - want).max(1)
    # ... where the map's SH is far from it (the disc is a third of the power), and peaks + residual is the map
    assert np.abs(env.to_sh(4) - want).max() > 0.1 * np.abs(want[0]).min()
    np.testing.assert_allclose(split.to_sh(4), env.to_sh(4), atol=1e-3 * np.abs(want[0]).min())
    # the residual is smooth: nothing left above the sky's brightest value anywhere
    assert float(split.residual.image.max()) <= float((SKY_A + SKY_B).max()) * 1.01


def test_a_sun_sized_disc_of_one_or_two_pixels() -> None:
    """The real sun (0.265 deg) on a 1k-wide map (0.35 deg pixels): found within a pixel, its power kept."""
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    h, r, rad = 512, math.radians(0.265), np.array([9e4, 8e4, 7e4])
    center = _dir(30.0, 40.0)
    env = _map([(center, r, rad)], h=h)
    split = split_envmap(env)
    assert len(split.peaks) == 1
    p = split.peaks[0]
    assert _angle_deg(p.direction, center) < 180.0 / h
    disc_power = rad * 2 * np.pi * (1 - math.cos(r))
    np.testing.assert_allclose(p.power, disc_power, rtol=0.02)
    np.testing.assert_allclose(_split_power(split), 4 * np.pi * SKY_A + disc_power, rtol=0.01)
    assert 0.25 * disc_power[0] / rad[0] < p.solid_angle < 8 * disc_power[0] / rad[0]  # within a few pixels' size
    # a fixed radius keeps the power and moves the radiance
    fixed = split_envmap(env, angular_radius=r).peaks[0]
    assert fixed.angular_radius == pytest.approx(r)
    np.testing.assert_allclose(fixed.power, p.power, rtol=1e-9)


def test_up_to_k_peaks_strongest_first() -> None:
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    strong, weak = _dir(50.0, 10.0), _dir(15.0, 200.0)
    env = _map([(strong, math.radians(3.0), DISC_RAD), (weak, math.radians(3.0), 0.5 * DISC_RAD)])
    one, two = split_envmap(env, max_peaks=1), split_envmap(env, max_peaks=2)
    assert len(one.peaks) == 1 and len(two.peaks) == 2
    assert _angle_deg(one.peaks[0].direction, strong) < 180.0 / H
    assert _angle_deg(two.peaks[1].direction, weak) < 180.0 / H
    assert two.shares()[0] > two.shares()[1] > 0
    for s in (one, two):
        np.testing.assert_allclose(_split_power(s), np.einsum("hw,hwc->c", _pixel_omega(H), env.image), rtol=0.01)
    none = split_envmap(env, max_peaks=0)
    assert none.peaks == [] and np.array_equal(none.residual.image, env.image)


def test_the_procedural_sky_sun_is_a_peak_by_construction() -> None:
    sun, e = _dir(40.0, 300.0), np.array([8.0, 7.4, 6.4])
    sky, ground = np.array([0.35, 0.55, 1.0]), np.array([0.25, 0.22, 0.2])
    split = split_sky(sun, e, sky, ground)
    assert len(split.peaks) == 1
    p = split.peaks[0]
    np.testing.assert_allclose(p.direction, sun, atol=1e-12)
    assert math.degrees(p.angular_radius) == pytest.approx(0.265, abs=0.01)  # the real sun
    assert p.solid_angle == pytest.approx(6.7e-5, rel=0.01)
    np.testing.assert_allclose(p.radiance * 2 * np.pi * (1 - math.cos(p.angular_radius)), e, rtol=1e-9)
    # energy against quadrature of the CIE formula: Gauss-Legendre in z over the upper hemisphere x 512 azimuths,
    # plus the ground's 2 pi and the sun's E
    z, wz = np.polynomial.legendre.leggauss(256)
    z, wz = 0.5 * (z + 1), 0.5 * wz
    phi = 2 * np.pi * (np.arange(512) + 0.5) / 512
    s = np.sqrt(1 - z * z)
    d = np.stack(np.broadcast_arrays(s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), z[:, None]), -1)
    sky_int = float((cie_clear_sky(d, sun) * wz[:, None]).sum() * 2 * np.pi / 512)
    want = sky_int * sky + 2 * np.pi * ground + e
    np.testing.assert_allclose(_split_power(split), want, rtol=0.01)
    # the residual is the sky without its sun: its SH is today's sky SH minus the sun's cap
    from prt_torch.light.sources import sky_sh

    full = sky_sh(4, sun, e, sky, ground)
    np.testing.assert_allclose(split.to_sh(4), full, atol=1e-9)
    np.testing.assert_allclose(split.residual.to_sh(4), full - p.to_sh(4), atol=1e-9)
    # a configurable radius, and no peak for a sun below the horizon
    wide = split_sky(sun, e, sky, ground, sun_angular_radius=math.radians(2.0)).peaks[0]
    assert wide.angular_radius == pytest.approx(math.radians(2.0))
    np.testing.assert_allclose(wide.power, e, rtol=1e-9)
    assert split_sky(_dir(-5.0, 0.0), e, sky, ground).peaks == []


def test_json_round_trip_and_schema() -> None:
    p = PeakLight(_dir(10.0, 20.0), math.radians(1.5), np.array([1.0, 2.0, 3.0]))
    d = p.to_dict()
    assert set(d) == {"direction", "angular_radius_deg", "radiance"} and d["angular_radius_deg"] == pytest.approx(1.5)
    q = PeakLight.from_dict(d)
    np.testing.assert_allclose(q.direction, p.direction)
    np.testing.assert_allclose(q.radiance, p.radiance)
    assert q.angular_radius == pytest.approx(p.angular_radius)
    el, az = p.elevation_azimuth_deg
    assert (el, az) == (pytest.approx(10.0), pytest.approx(20.0))
    # the peak's SH is a cap: at order 1 its DC term is power / sqrt(4 pi)
    np.testing.assert_allclose(p.to_sh(1)[0], p.power / math.sqrt(4 * np.pi))
    assert sh_basis(p.direction, 1)[0] == pytest.approx(1 / math.sqrt(4 * np.pi))


@pytest.mark.parametrize("k", [-1, MAX_PEAKS + 1, 2.0, True, "2"])
def test_bad_peak_counts_are_one_line_errors(k: object) -> None:
    env = _map([], h=16)
    with pytest.raises(PrtError, match=r"max_peaks must be an integer in 0\.\.4") as exc:
        split_envmap(env, max_peaks=k)  # type: ignore[arg-type]
    assert "\n" not in str(exc.value)


def test_bad_arguments_are_one_line_errors() -> None:
    with pytest.raises(PrtError, match="angular radius"):
        split_sky(sun_angular_radius=0.0)
    with pytest.raises(PrtError, match="angular radius"):
        PeakLight(_dir(0, 0), math.radians(120.0), np.ones(3))
    with pytest.raises(PrtError, match="radiance"):
        PeakLight(_dir(0, 0), 0.01, -np.ones(3))
    with pytest.raises(PrtError, match="needs 'radiance'"):
        PeakLight.from_dict({"direction": [0, 0, 1], "angular_radius_deg": 1.0})
    with pytest.raises(PrtError, match="sun color"):
        split_sky(sun_color=(1.0, 2.0))
    with pytest.raises(PrtError, match="expects an EnvMap"):
        split_envmap(np.ones((4, 8, 3)))  # type: ignore[arg-type]


def test_a_disc_on_an_angular_map() -> None:
    """The probe layout: a disc rendered at the pixel centres (the library's probe mapping, tested against
    Debevec's formula in test_envmap.py) is found, and energy is kept with the probe's own pixel solid angles."""
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    from prt_torch.light.envmap import probe_directions, probe_solid_angles

    n, center, r = 256, _dir(25.0, 250.0), math.radians(5.0)
    d = probe_directions(n, n)
    img = np.ones((n, n, 3)) + (d @ center >= math.cos(r))[..., None] * DISC_RAD
    env = EnvMap(img.astype(np.float32), "probe")
    split = split_envmap(env)
    assert len(split.peaks) == 1
    p = split.peaks[0]
    assert _angle_deg(p.direction, center) < 1.0 and abs(math.degrees(p.angular_radius) - 5.0) < 1.0
    om = probe_solid_angles(n, n)
    map_power = np.einsum("hw,hwc->c", om, img)
    got = p.power + np.einsum("hw,hwc->c", om, split.residual.image.astype(np.float64))
    np.testing.assert_allclose(got, map_power, rtol=0.01)
    np.testing.assert_allclose(p.power, DISC_RAD * 2 * np.pi * (1 - math.cos(r)), rtol=0.05)
