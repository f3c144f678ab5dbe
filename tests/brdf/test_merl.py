"""MERL reader: a file written by hand in the MERL format, and an analytic BRDF round trip."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from prt_torch.brdf.analytic import CookTorrance
from prt_torch.brdf.merl import MerlBRDF, write_merl
from prt_torch.brdf.rpo import build_rpo
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import sphere_quadrature


def _g(th: np.ndarray, td: np.ndarray, pd: np.ndarray) -> np.ndarray:
    """A smooth test function of the Rusinkiewicz angles, symmetric under phi_d -> phi_d + pi."""
    return 1.0 + 0.5 * np.cos(th) ** 2 + 0.3 * np.sin(td) + 0.2 * np.cos(2 * pd)


def _pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        d = rng.normal(size=(n, 3))
        d[:, 2] = np.abs(d[:, 2]) + 0.2
        out.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    return out[0], out[1]


def test_hand_written_file(tmp_path: Path) -> None:
    # independent writer: header (90, 90, 180) int32, then R, G, B float64 blocks at the bin centres, divided
    # by the channel scales; theta_h bins are quadratic (theta_h = (i/90)^2 * 90 degrees)
    ih, idd, ip = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th = ((ih + 0.5) / 90) ** 2 * (math.pi / 2)
    td = (idd + 0.5) / 90 * (math.pi / 2)
    pd = (ip + 0.5) / 180 * math.pi
    g = _g(th, td, pd).ravel()
    chans = np.stack([g * 1.0, g * 0.5, g * 0.25])
    scales = np.array([1.0, 1.15, 1.66])[:, None] / 1500
    p = tmp_path / "hand.binary"
    p.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + (chans / scales).astype("<f8").tobytes())

    brdf = MerlBRDF.load(p)
    wi, wo = _pairs(4000, 1)
    # reference angles, computed with an explicit frame at h (not the reader's two rotations)
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th_r = np.arccos(h[:, 2])
    ph = np.arctan2(h[:, 1], h[:, 0])
    e1 = np.stack([np.cos(th_r) * np.cos(ph), np.cos(th_r) * np.sin(ph), -np.sin(th_r)], -1)
    e2 = np.stack([-np.sin(ph), np.cos(ph), np.zeros_like(ph)], -1)
    td_r = np.arccos(np.clip((wi * h).sum(1), -1, 1))
    pd_r = np.arctan2((wi * e2).sum(1), (wi * e1).sum(1))
    ref = _g(th_r, td_r, pd_r)
    got = brdf(wi, wo)
    np.testing.assert_allclose(got / np.array([1.0, 0.5, 0.25]), np.repeat(ref[:, None], 3, 1), rtol=0.03)
    # shape is the channel mean; tint the albedo ratios (here exactly the channel ratios)
    np.testing.assert_allclose(brdf.tint, np.array([1.0, 0.5, 0.25]) / (1.75 / 3), rtol=1e-9)
    np.testing.assert_allclose(brdf.shape(wi, wo), got.mean(1), rtol=1e-12)


def test_analytic_roundtrip_and_rpo(tmp_path: Path) -> None:
    ct = CookTorrance(roughness=0.7, f0=0.1, kd=0.4, ks=0.6, tint=[0.8, 0.6, 0.4])
    p = tmp_path / "ct.binary"
    write_merl(p, ct)
    assert p.stat().st_size == 12 + 3 * 90 * 90 * 180 * 8
    m = MerlBRDF.load(p)
    wi, wo = _pairs(4000, 2)
    a, b = ct(wi, wo), m(wi, wo)
    rel = np.linalg.norm(a - b) / np.linalg.norm(a)
    assert rel < 0.03, rel  # nearest-bin lookup of a smooth BRDF
    np.testing.assert_allclose(m.tint, ct.tint / ct.tint.mean(), rtol=1e-6)
    ra = build_rpo(ct, order=4, k=8, n_theta=12, n_phi=24)
    rm = build_rpo(m, order=4, k=8, n_theta=12, n_phi=24)
    print(f"\nMERL round trip: lookup rel error {rel:.4f}; RPO rel error analytic {ra.rel_error:.4f} "
          f"measured {rm.rel_error:.4f}; SH rel error {ra.sh_rel_error:.4f} / {rm.sh_rel_error:.4f}")
    assert abs(ra.sh_rel_error - rm.sh_rel_error) < 0.03
    # the RGB separable approximations tint * sum_b (u_b . y(wi)) (w_b . y(wo)) agree as functions on
    # (sphere of wi) x (hemisphere of wo) (individual factors and coefficients may mix / rescale)
    d, w = sphere_quadrature(12)
    up = d[:, 2] > 0
    y = sh_basis(d, 4)

    def fn(r: object) -> np.ndarray:
        return np.einsum("ib,jb,c->ijc", y @ r.u.T.astype(np.float64), y[up] @ r.w.T.astype(np.float64), r.tint)

    ww = (w[:, None] * w[None, up])[..., None]
    fa, fm = fn(ra), fn(rm)
    diff = math.sqrt((ww * (fa - fm) ** 2).sum() / (ww * fa**2).sum())
    print(f"separable RGB approximations differ by {diff:.4f} (relative L2)")
    assert diff < 0.03, diff


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="not found"):
        MerlBRDF.load(tmp_path / "none.binary")
    p = tmp_path / "dims.binary"
    p.write_bytes(np.array([10, 10, 10], "<i4").tobytes() + b"\0" * 64)
    with pytest.raises(PrtError, match="dimensions"):
        MerlBRDF.load(p)
    q = tmp_path / "short.binary"
    q.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + b"\0" * 64)
    with pytest.raises(PrtError, match="bytes, expected"):
        MerlBRDF.load(q)
