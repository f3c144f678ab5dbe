"""The peak lights' direct term (:func:`prt_torch.brdf.direct.peak_radiance`) vs numerical quadrature of the
rendering integral over the disc: ``int_disc L f_r(w, v) max(n . w, 0) dw``, which tends to ``E f_r(l, v) max(n . l,
0)`` (``E = L Omega``) as the disc shrinks; the error of evaluating at the centre is second order in the radius (the
integrand's first-order variation integrates to 0 over a symmetric disc), so for a 0.5-degree disc it is ~1e-4
relative for the smooth lobes used here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.brdf.analytic import CookTorrance, Lambert, Phong
from prt_torch.brdf.direct import peak_radiance, view_directions
from prt_torch.errors import PrtError


def _frame(n: np.ndarray) -> np.ndarray:
    """A frame ``(3, 3)`` rows ``(t, b, n)`` for the unit normal ``n``."""
    t = np.cross([0.0, 1.0, 0.3], n)
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n])


def _disc_quadrature(brdf, frame: np.ndarray, view: np.ndarray, axis: np.ndarray, half: float, radiance: np.ndarray,
                     n: int = 96) -> np.ndarray:
    """``int_disc L f_r max(cos, 0) dw`` by the midpoint rule in ``(cos theta, phi)`` about ``axis`` (exact
    solid-angle weights ``d(cos theta) d phi``)."""
    ct = 1 - (np.arange(n) + 0.5) / n * (1 - math.cos(half))
    ph = (np.arange(4 * n) + 0.5) / (4 * n) * 2 * math.pi
    c, p = np.meshgrid(ct, ph, indexing="ij")
    s = np.sqrt(1 - c * c)
    t = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    b = np.cross(axis, t)
    w = (s * np.cos(p))[..., None] * t + (s * np.sin(p))[..., None] * b + c[..., None] * axis
    w = w.reshape(-1, 3)
    wi = w @ frame.T
    wo = np.broadcast_to(frame @ view, wi.shape).copy()
    f = brdf(wi, wo) * np.maximum(wi[:, 2], 0.0)[:, None]
    dw = (1 - math.cos(half)) / n * 2 * math.pi / (4 * n)
    return (f * dw).sum(0) * radiance


@pytest.mark.parametrize("brdf", [Lambert(tint=(0.8, 0.6, 0.4)), Phong(exponent=16, kd=0.3, ks=0.7),
                                  CookTorrance(roughness=0.5, f0=0.04, kd=0.5, ks=0.5)], ids=lambda b: b.name)
def test_peak_term_matches_quadrature_over_a_small_disc(brdf) -> None:
    rng = np.random.default_rng(4)
    half = math.radians(0.5)
    radiance = np.array([3.0e4, 2.8e4, 2.4e4])
    omega = 2 * math.pi * (1 - math.cos(half))
    frames, views, want = [], [], []
    axis = np.array([0.3, -0.4, 0.8]) / np.linalg.norm([0.3, -0.4, 0.8])
    while len(frames) < 6:  # normals facing the light and the viewer, off the grazing band
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        if n @ axis < 0.2 or n @ v < 0.2:
            continue
        frames.append(_frame(n))
        views.append(v)
        want.append(_disc_quadrature(brdf, frames[-1], v, axis, half, radiance))
    got = peak_radiance(np.array(frames), np.array(views), axis[None], (radiance * omega)[None],
                        np.ones((len(frames), 1)), brdf)
    np.testing.assert_allclose(got, np.array(want), rtol=2e-3)


def test_peak_term_is_linear_in_visibility_and_sums_peaks() -> None:
    brdf = Phong(exponent=16, kd=0.3, ks=0.7)
    rng = np.random.default_rng(1)
    n = rng.normal(size=(2, 5, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    frames = np.stack([np.stack([_frame(x) for x in row]) for row in n])  # (2, 5, 3, 3)
    pos = rng.normal(size=(2, 5, 3))
    view = view_directions(pos, np.array([0.0, -4.0, 1.0]))
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    powers = np.array([[5.0, 4.0, 3.0], [1.0, 1.0, 1.0]])
    vis = rng.random((2, 5, 2))
    both = peak_radiance(frames, view, dirs, powers, vis, brdf)
    one = [peak_radiance(frames, view, dirs[p:p + 1], powers[p:p + 1], vis[..., p:p + 1], brdf) for p in range(2)]
    np.testing.assert_allclose(both, one[0] + one[1], rtol=1e-6)
    half = peak_radiance(frames, view, dirs, powers, vis / 2, brdf)
    np.testing.assert_allclose(half, both / 2, rtol=1e-6)
    # a normal facing away from the light reflects none of it
    down = peak_radiance(frames[:1, :1], view[:1, :1], -frames[0, 0, 2][None], powers[:1], np.ones((1, 1, 1)), brdf)
    assert np.all(down == 0)


def test_peak_term_shape_errors_are_one_line() -> None:
    with pytest.raises(PrtError, match="peak visibility"):
        peak_radiance(np.tile(np.eye(3), (4, 1, 1)), np.tile([0.0, 0.0, 1.0], (4, 1)), np.array([[0.0, 0.0, 1.0]]),
                      np.ones((1, 3)), np.ones((4, 2)), Lambert())
