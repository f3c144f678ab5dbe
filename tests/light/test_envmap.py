"""Environment-map geometry and SH projection vs scipy quadrature, closed forms and published values."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

from prt_torch.errors import PrtError
from prt_torch.light.envmap import (
    EnvMap,
    envmap_to_sh,
    latlong_directions,
    latlong_pixel_coords,
    latlong_solid_angles,
    load_envmap,
    probe_directions,
    probe_pixel_coords,
    probe_solid_angles,
)
from prt_torch.light.readers import write_pfm
from prt_torch.sh.basis import sh_basis


def _dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_latlong_solid_angles_exact() -> None:
    h, w = 16, 32
    om = latlong_solid_angles(h, w)
    assert om.sum() == pytest.approx(4 * math.pi, rel=1e-13)
    for row in (0, 5, 15):  # scipy double integral of sin(theta) over the pixel
        ref, _ = integrate.dblquad(lambda t, p: math.sin(t), 0, 2 * math.pi / w,
                                   math.pi * row / h, math.pi * (row + 1) / h)
        assert om[row, 3] == pytest.approx(ref, rel=1e-10)


def test_probe_solid_angles_vs_scipy() -> None:
    n = 32
    om = probe_solid_angles(n, n)
    assert om.sum() == pytest.approx(4 * math.pi, rel=1e-5)
    # reference: exact solid angle of the pixel's image on the sphere, by scipy over the pixel square
    for row, col in [(16, 16), (3, 20), (0, 13), (10, 2)]:
        a0, a1 = 2 * col / n - 1, 2 * (col + 1) / n - 1
        b1, b0 = 1 - 2 * row / n, 1 - 2 * (row + 1) / n

        def jac(b: float, a: float) -> float:
            r = math.hypot(a, b)
            return 0.0 if r > 1 else (math.pi**2 if r == 0 else math.pi * math.sin(math.pi * r) / r)

        ref, _ = integrate.dblquad(jac, a0, a1, b0, b1, epsabs=1e-10)
        assert om[row, col] == pytest.approx(ref, rel=2e-3, abs=1e-7)


def test_documented_axes() -> None:
    d = latlong_directions(64, 128)
    assert d[0, 40, 2] > 0.999 and d[-1, 40, 2] < -0.999  # row 0 = +z (up)
    # middle row, the two centre columns straddle +y (left one toward -x): centre of the image = +y
    np.testing.assert_allclose(latlong_directions(3, 6)[1, 2:4], [[-math.cos(math.pi / 3), math.sin(math.pi / 3), 0],
                                                                  [math.cos(math.pi / 3), math.sin(math.pi / 3), 0]],
                               atol=1e-12)
    uv = latlong_pixel_coords(np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]]))
    np.testing.assert_allclose(uv[:, 0], [0.75, 0.5, 0.25, 0.0], atol=1e-12)
    np.testing.assert_allclose(uv[:, 1], 0.5, atol=1e-12)
    # probe: centre -> -y, top-centre of the disk (r = 1/2 upward) -> +z, right -> +x, rim -> +y
    uv = probe_pixel_coords(np.array([[0, -1.0, 0], [0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]]))
    np.testing.assert_allclose(uv[:3], [[0.5, 0.5], [0.5, 0.25], [0.75, 0.5]], atol=1e-12)
    assert math.hypot(uv[3, 0] - 0.5, uv[3, 1] - 0.5) == pytest.approx(0.5)


def test_inverse_mappings_roundtrip() -> None:
    h, w = 32, 64
    d = latlong_directions(h, w)
    uv = latlong_pixel_coords(d)
    np.testing.assert_allclose(uv[..., 0] * w - 0.5, np.broadcast_to(np.arange(w), (h, w)), atol=1e-9)
    np.testing.assert_allclose(uv[..., 1] * h - 0.5, np.broadcast_to(np.arange(h)[:, None], (h, w)), atol=1e-9)
    n = 40
    d = probe_directions(n, n)
    a = 2 * (np.arange(n) + 0.5) / n - 1
    inside = np.hypot(a[None, :], a[:, None]) < 1  # pixel centre inside the disk
    uv = probe_pixel_coords(d)
    cols = np.broadcast_to(np.arange(n), (n, n))
    np.testing.assert_allclose((uv[..., 0] * n - 0.5)[inside], cols[inside], atol=1e-8)
    np.testing.assert_allclose((uv[..., 1] * n - 0.5)[inside], cols.T[inside], atol=1e-8)


def _render(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    return (sh_basis(dirs, 3) @ sh).astype(np.float32)


@pytest.mark.parametrize("layout", ["latlong", "probe"])
def test_projection_recovers_band_limited_lighting(layout: str) -> None:
    rng = np.random.default_rng(3)
    sh = rng.normal(size=(9, 3))
    h = 128
    dirs = latlong_directions(h, 2 * h) if layout == "latlong" else probe_directions(256, 256)
    env = EnvMap(_render(sh, dirs), layout)  # type: ignore[arg-type]
    got = envmap_to_sh(env, 3)
    # float32 pixels + midpoint rule: second-order accurate in the pixel size
    np.testing.assert_allclose(got, sh, atol=2e-3 * np.abs(sh).max())
    # higher bands of a band-limited map are ~0 (orthogonality of the quadrature)
    assert np.abs(envmap_to_sh(env, 5)[9:]).max() < 3e-3 * np.abs(sh).max()


def test_constant_map_l00_exact() -> None:
    env = EnvMap(np.ones((32, 64, 3), np.float32), "latlong")
    np.testing.assert_allclose(envmap_to_sh(env, 2), [[math.sqrt(4 * math.pi)] * 3] + [[0.0] * 3] * 3, atol=1e-12)


def test_shared_maps_match_published_l00(shared_data: Path) -> None:
    # SOURCES.md: L00 in the lat-long frame, z up (orthonormal y00 = 1/(2 sqrt(pi)), exact solid angles)
    u = load_envmap(shared_data / "envmaps" / "uffizi.hdr")
    assert u.layout == "latlong"
    np.testing.assert_allclose(u.to_sh(1)[0], [3.172, 3.077, 3.501], atol=6e-4)
    m = load_envmap(shared_data / "envmaps" / "spiaggia_di_mondello_1k.hdr")
    np.testing.assert_allclose(m.to_sh(1)[0], [2.879, 2.999, 3.110], atol=6e-4)
    # upper half ~20x brighter (SOURCES.md) -> strongly positive y_10 (z) coefficient
    assert (u.to_sh(2)[2] > 0.8 * u.to_sh(2)[0]).all()


def test_layouts_agree_on_the_same_scene(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    sh = rng.normal(size=(9, 3))
    write_pfm(tmp_path / "ll.pfm", _render(sh, latlong_directions(96, 192)))
    write_pfm(tmp_path / "pr.pfm", _render(sh, probe_directions(192, 192)))
    a = load_envmap(tmp_path / "ll.pfm")
    b = load_envmap(tmp_path / "pr.pfm")
    assert (a.layout, b.layout) == ("latlong", "probe")
    np.testing.assert_allclose(a.to_sh(3), b.to_sh(3), atol=4e-3 * np.abs(sh).max())


def test_light_package_imports_without_torch(tmp_path: Path) -> None:
    import subprocess
    import sys

    write_pfm(tmp_path / "m.pfm", np.ones((8, 16, 3), np.float32))
    code = ("import sys; from prt_torch.light import load_envmap, sky_sh; load_envmap(sys.argv[1]).to_sh(3); "
            "sky_sh(3, height=8); assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "m.pfm")], check=True)


def test_bad_inputs(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="shape"):
        EnvMap(np.ones((4, 8)), "latlong")
    with pytest.raises(PrtError, match="2:1"):
        EnvMap(np.ones((4, 4, 3)), "latlong")
    with pytest.raises(PrtError, match="square"):
        EnvMap(np.ones((4, 8, 3)), "probe")
    with pytest.raises(PrtError, match="layout"):
        EnvMap(np.ones((4, 8, 3)), "cube")  # type: ignore[arg-type]
    env = EnvMap(np.ones((4, 8, 3)), "latlong")
    for order in (0, 17, 2.5):
        with pytest.raises(PrtError, match="unsupported SH order"):
            envmap_to_sh(env, order)  # type: ignore[arg-type]
    write_pfm(tmp_path / "odd.pfm", np.ones((5, 7, 3)))
    with pytest.raises(PrtError, match="cannot infer"):
        load_envmap(tmp_path / "odd.pfm")
    with pytest.raises(PrtError, match="layout"):
        load_envmap(tmp_path / "odd.pfm", layout="spherical")
    with pytest.raises(PrtError, match="unit"):
        latlong_pixel_coords(np.array([[1.0, 1.0, 0.0]]))
    assert _dirs(3).shape == (3, 3)
