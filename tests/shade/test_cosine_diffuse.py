"""Cosine product matrix (eq. 14) and diffuse PRT shading vs quadrature and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.brdf.factor import hemisphere_rule
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import sphere_quadrature
from prt_torch.sh.zonal import clamped_cosine_zh, hemisphere_zh, zh_to_sh
from prt_torch.shade.cosine import cosine_product_matrix
from prt_torch.shade.diffuse import shade_diffuse_prt


def test_cosine_product_matrix_vs_quadrature() -> None:
    n = 4
    # c_k = int max(z, 0) y_k: exact on the hemisphere product rule (a polynomial there)
    dh, wh = hemisphere_rule(8, 16)
    c = (sh_basis(dh, n) * (dh[:, 2] * wh)[:, None]).sum(0)
    d, w = sphere_quadrature(3 * (n - 1))
    y = sh_basis(d, n)
    ref = np.einsum("ni,nj,n->ij", y, y, (y @ c) * w)  # sum_k c_k Gamma_ijk
    got = cosine_product_matrix(n)
    np.testing.assert_allclose(got, ref, atol=1e-12)
    np.testing.assert_allclose(got, got.T, atol=1e-15)
    # a tilted normal: eq. 14 with N_x
    nrm = np.array([0.6, 0.0, 0.8])
    c2 = zh_to_sh(clamped_cosine_zh(n), nrm)
    np.testing.assert_allclose(cosine_product_matrix(n, nrm) @ c2, np.einsum("ni,n->i", y, (y @ c2) ** 2 * w),
                               atol=1e-12)


def test_uniform_unshadowed_irradiance_is_pi() -> None:
    for n in (2, 3, 4, 6):
        v = zh_to_sh(hemisphere_zh(n), np.array([0.0, 0.0, 1.0]))
        l = np.zeros(n * n)
        l[0] = math.sqrt(4 * math.pi)
        assert l @ cosine_product_matrix(n) @ v == pytest.approx(math.pi, rel=1e-12)


def test_diffuse_prt_vs_quadrature() -> None:
    n = 4
    rng = np.random.default_rng(0)
    l = rng.normal(size=(n * n, 3))
    normals = rng.normal(size=(5, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t = zh_to_sh(clamped_cosine_zh(n), normals) / math.pi  # unshadowed transfer, 1/pi inside
    albedo = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    got = shade_diffuse_prt(torch.from_numpy(t), torch.from_numpy(l), albedo).numpy()
    d, w = sphere_quadrature(40)
    L = sh_basis(d, n) @ l  # band-limited radiance, so the truncated cosine is exact
    ref = np.stack([((L * (np.maximum(d @ nn, 0) * w)[:, None]).sum(0)) / math.pi for nn in normals])
    np.testing.assert_allclose(got, ref * albedo.numpy(), atol=2e-3 * np.abs(ref).max())
    # uniform unit environment: radiance = albedo (irradiance pi)
    lu = np.zeros((n * n, 3))
    lu[0] = math.sqrt(4 * math.pi)
    np.testing.assert_allclose(shade_diffuse_prt(torch.from_numpy(t), torch.from_numpy(lu)).numpy(), 1.0, rtol=1e-12)


def test_bad_inputs() -> None:
    with pytest.raises(PrtError, match="lighting must have shape"):
        shade_diffuse_prt(torch.zeros(3, 16), torch.zeros(9, 3))
    with pytest.raises(PrtError, match="NaN"):
        shade_diffuse_prt(torch.full((3, 9), float("nan")), torch.zeros(9, 3))
    with pytest.raises(PrtError, match="transfer must have shape"):
        shade_diffuse_prt(torch.zeros(9), torch.zeros(9, 3))
    with pytest.raises(PrtError, match="unsupported SH order"):
        cosine_product_matrix(9)
    with pytest.raises(PrtError, match="unit"):
        cosine_product_matrix(3, np.array([1.0, 1.0, 0.0]))
