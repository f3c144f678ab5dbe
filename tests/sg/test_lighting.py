"""Multiscale HEALPix SG fit and peak detection (seed 004 sec. 6) on synthetic maps with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")

from prt_torch.errors import PrtError  # noqa: E402
from prt_torch.light.envmap import EnvMap, latlong_directions, probe_directions  # noqa: E402
from prt_torch.sg.algebra import sg_eval  # noqa: E402
from prt_torch.sg.lighting import detect_peaks, fit_envmap_sg, healpix_directions  # noqa: E402

H = 128  # lat-long maps are H x 2H (pixel 1.4 degrees)


def _sg_map(axes: np.ndarray, lam: np.ndarray, mu: np.ndarray, base: float, dirs: np.ndarray) -> np.ndarray:
    v = sg_eval(torch.as_tensor(axes), torch.as_tensor(lam), torch.as_tensor(mu),
                torch.as_tensor(dirs.reshape(-1, 3))).numpy()
    return (v.reshape(*dirs.shape[:-1], 3) + base).astype(np.float32)


def _unit(v: list[float]) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return a / np.linalg.norm(a)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1, 1))))


def test_residual_fit_converges_on_a_sum_of_sgs() -> None:
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(5, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    lam = np.array([3.0, 10.0, 30.0, 60.0, 120.0])
    mu = rng.uniform(0.5, 3.0, (5, 3))
    env = EnvMap(_sg_map(axes, lam, mu, 0.1, latlong_directions(H, 2 * H)), "latlong")
    fit = fit_envmap_sg(env, max_level=4, rel_threshold=0.0, peaks=False, separate_peaks=False)
    e = fit.rel_error_per_scale
    assert len(e) == 5 and fit.nsides == [1, 2, 4, 8, 16]
    assert all(b < a for a, b in zip(e, e[1:], strict=False)), e  # the residual decreases at every scale
    assert e[-1] < 0.02, e
    # the fitted lighting at the lobe centres (the map's peaks) is the map's value there
    ref = _sg_map(axes, lam, mu, 0.1, axes)
    assert np.abs(fit.eval(axes) / ref - 1).max() < 0.03
    # ... and the fitted maxima sit on them: the brightest fitted sample near each sharp lobe is within a pixel
    grid = healpix_directions(32)
    val = fit.eval(grid).sum(1)
    for k in (3, 4):
        near = grid @ axes[k] > math.cos(math.radians(8))
        best = grid[near][np.argmax(val[near])]
        assert _angle(best, axes[k]) < math.degrees(math.sqrt(4 * math.pi / (12 * 32**2))), k
    # the threshold stops early; total power is preserved
    early = fit_envmap_sg(env, max_level=4, rel_threshold=0.1, peaks=False, separate_peaks=False)
    assert len(early.rel_error_per_scale) < 5 and early.rel_error_per_scale[-1] <= 0.1
    power = (env.image * env.solid_angles()[..., None]).sum((0, 1))
    np.testing.assert_allclose(fit.lobes.integral().numpy(), power, rtol=0.01)


def test_residual_fit_on_a_light_probe() -> None:
    axes = np.stack([_unit([0.3, -0.9, 0.3]), _unit([-0.5, 0.5, -0.7])])  # one on the probe's front, one near its rim
    lam, mu = np.array([8.0, 40.0]), np.array([[2.0, 1.5, 1.0], [1.0, 2.0, 3.0]])
    env = EnvMap(_sg_map(axes, lam, mu, 0.2, probe_directions(2 * H, 2 * H)), "probe")
    fit = fit_envmap_sg(env, max_level=3, rel_threshold=0.0, peaks=False)
    e = fit.rel_error_per_scale
    assert all(b < a for a, b in zip(e, e[1:], strict=False)) and e[-1] < 0.05, e
    assert np.abs(fit.eval(axes) / _sg_map(axes, lam, mu, 0.2, axes) - 1).max() < 0.05


def test_sharp_lobes_are_found_as_peaks() -> None:
    axes = np.stack([_unit([1, 0.2, 0.3]), _unit([-0.3, -1, 0.5]), _unit([0.1, 0.4, -1])])
    lam = np.full(3, 3000.0)
    mu = np.array([[400.0, 380, 350], [300, 300, 300], [500, 450, 400]])
    env = EnvMap(_sg_map(axes, lam, mu, 0.5, latlong_directions(2 * H, 4 * H)), "latlong")
    peaks = detect_peaks(env)
    assert len(peaks) == 3
    pixel = math.degrees(math.sqrt(4 * math.pi / (12 * 64**2)))  # the default detection grid for 256 x 512
    for p in peaks:
        k = int(np.argmax(axes @ p.direction))
        assert _angle(p.direction, axes[k]) < pixel
        true_power = mu[k] * 2 * math.pi / lam[k]
        np.testing.assert_allclose(p.power, true_power, rtol=0.1)
        assert len(p.lobes) == 1 and _angle(p.lobes.axis[0].double().numpy(), axes[k]) < pixel
    # strongest first
    assert [round(float(p.power.sum()), 3) for p in peaks] == sorted((round(float(p.power.sum()), 3)
                                                                       for p in peaks), reverse=True)


def _disk_map(center: np.ndarray, radius_deg: float, radiance: float, dirs: np.ndarray) -> np.ndarray:
    img = np.full((*dirs.shape[:-1], 3), 0.5, np.float32)
    img[dirs @ center >= math.cos(math.radians(radius_deg))] = radiance
    return img


@pytest.mark.parametrize(("center", "layout"), [
    (_unit([0.6, 0.5, 0.62]), "latlong"),
    (_unit([0.0, -1.0, 0.05]), "latlong"),  # world -y: the lat-long seam (left/right edges)
    (_unit([0.02, 0.03, 1.0]), "latlong"),  # the north pole: a disk over the whole top rows
    (_unit([0.3, 0.2, -0.93]), "probe"),  # a light probe
    (_unit([0.0, 1.0, 0.0]), "probe"),  # the probe's rim (world +y): the disk wraps around the circle
])
def test_disk_light_direction_and_solid_angle(center: np.ndarray, layout: str) -> None:
    radius = 6.0
    dirs = latlong_directions(2 * H, 4 * H) if layout == "latlong" else probe_directions(4 * H, 4 * H)
    env = EnvMap(_disk_map(center, radius, 60.0, dirs), layout)
    peaks = detect_peaks(env)
    assert len(peaks) == 1, [p.direction for p in peaks]
    p = peaks[0]
    omega = 2 * math.pi * (1 - math.cos(math.radians(radius)))
    # measured: within 0.13 degrees, solid angle and power within 1.3 % (map pixels 0.7 degrees)
    assert _angle(p.direction, center) < 0.3
    assert abs(p.solid_angle / omega - 1) < 0.05, (p.solid_angle, omega)
    np.testing.assert_allclose(p.power, 60.0 * omega, rtol=0.05)
    assert 1 <= len(p.lobes) <= 3
    np.testing.assert_allclose(p.lobes.integral().double().numpy().sum(), 3 * (60.0 - 0.5) * omega, rtol=0.15)


def test_elongated_light_gets_several_lobes_and_separated_peaks_fit() -> None:
    dirs = latlong_directions(2 * H, 4 * H)
    a, b = _unit([1, 0, 0.3]), _unit([0.7, 0.7, 0.3])  # a bar of ~30 degrees
    t = np.linspace(0, 1, 60)[:, None]
    pts = (1 - t) * a + t * b
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    img = np.full((*dirs.shape[:-1], 3), 0.3, np.float32)
    img[(dirs.reshape(-1, 3) @ pts.T).max(1).reshape(dirs.shape[:-1]) > math.cos(math.radians(2))] = 40.0
    env = EnvMap(img, "latlong")
    fit = fit_envmap_sg(env, max_level=3, rel_threshold=0.0)
    assert len(fit.peaks) == 1 and len(fit.peaks[0].lobes) == 3
    assert fit.peaks_separated and all(b < a for a, b in zip(fit.rel_error_per_scale, fit.rel_error_per_scale[1:],
                                                              strict=False))
    power = (env.image * env.solid_angles()[..., None]).sum((0, 1))
    np.testing.assert_allclose(fit.lobes.integral().numpy(), power, rtol=0.02)


def test_bad_maps_are_one_line_errors() -> None:
    with pytest.raises(PrtError) as e:
        EnvMap(np.zeros((0, 0, 3), np.float32), "latlong")
    assert "\n" not in str(e.value)
    env = EnvMap(np.ones((8, 16, 3), np.float32), "latlong")
    env.image = np.zeros((0, 0, 3), np.float32)  # bypassing the constructor
    bad = EnvMap(np.ones((8, 16, 3), np.float32), "latlong")
    bad.image[2, 3] = np.nan
    cases = [(lambda: fit_envmap_sg(env), "empty"), (lambda: fit_envmap_sg(bad), "NaN"),
             (lambda: detect_peaks(bad), "NaN"),
             (lambda: fit_envmap_sg(EnvMap(np.zeros((8, 16, 3), np.float32), "latlong")), "black"),
             (lambda: fit_envmap_sg(EnvMap(np.ones((8, 16, 3), np.float32), "latlong"), max_level=12), "max_level"),
             (lambda: detect_peaks(EnvMap(np.ones((8, 16, 3), np.float32), "latlong"), nside=3), "power of two")]
    for call, match in cases:
        with pytest.raises(PrtError, match=match) as e:
            call()
        assert "\n" not in str(e.value)
    # a uniform map has no peak
    assert detect_peaks(EnvMap(np.ones((8, 16, 3), np.float32), "latlong")) == []
