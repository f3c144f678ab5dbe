"""RPO build / save / load: sizes, torch-free loading, conventions of M vs quadrature, the catalogue."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from prt_torch.brdf.analytic import CookTorrance, Lambert, Phong
from prt_torch.brdf.rpo import CATALOGUE, RPO, build_rpo, builtin_rpo
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import sphere_quadrature
from tests.tolerance import assert_bitwise


def test_save_load_roundtrip_and_size(tmp_path: Path) -> None:
    rpo = build_rpo(Phong(exponent=8.0, kd=0.3, ks=0.7, tint=[0.9, 0.5, 0.2]), order=4, k=8, n_theta=12, n_phi=24)
    size = rpo.save(tmp_path / "phong.npz")
    assert size == (tmp_path / "phong.npz").stat().st_size
    print(f"\nRPO phong k=8 n=4: file {size} bytes; paper count {rpo.paper_float_count} floats "
          f"= {4 * rpo.paper_float_count} bytes; stored floats {rpo.stored_float_count}")
    assert size < 10_000  # seed 003: under 10 KB for k = 8, order 4, float32
    assert rpo.paper_float_count == 8 * 16 * 17
    back = RPO.load(tmp_path / "phong.npz")
    for name in ("M", "u", "w", "tint"):
        assert_bitwise(getattr(back, name), getattr(rpo, name), why='npz round trip')
    assert (back.order, back.name, back.k) == (4, "phong", 8)
    assert back.rel_error == pytest.approx(rpo.rel_error) and back.sh_rel_error == pytest.approx(rpo.sh_rel_error)


def test_load_does_not_import_torch(tmp_path: Path) -> None:
    build_rpo(Lambert(), order=3, k=2, n_theta=6, n_phi=12).save(tmp_path / "l.npz")
    code = ("import sys; from prt_torch.brdf.rpo import RPO; r = RPO.load(sys.argv[1]); "
            "assert r.M.shape == (2, 9, 9); assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "l.npz")], check=True)


def test_product_matrices_match_quadrature() -> None:
    # M_b v must be the projection of U_b,n(w) V(w): int (u_b . y)(v . y) y dw, by exact quadrature
    rpo = build_rpo(CookTorrance(roughness=0.6, kd=0.2, ks=0.8), order=3, k=3, n_theta=10, n_phi=20)
    d, w = sphere_quadrature(3 * 2 + 1)
    y = sh_basis(d, 3)
    v = np.random.default_rng(0).normal(size=9)
    for b in range(3):
        ref = (y * ((y @ rpo.u[b].astype(np.float64)) * (y @ v) * w)[:, None]).sum(0)
        np.testing.assert_allclose(rpo.M[b] @ v, ref, atol=2e-6 * np.abs(ref).max())


def test_catalogue_cache(tmp_path: Path) -> None:
    a = builtin_rpo("lambert", order=3, k=2, cache_dir=tmp_path)
    files = list(tmp_path.glob("lambert_n3_k2_*.npz"))
    assert len(files) == 1
    b = builtin_rpo("lambert", order=3, k=2, cache_dir=tmp_path)  # loaded from the cache
    assert_bitwise(a.u, b.u, why='the same seeded build twice')
    assert set(CATALOGUE) == {"lambert", "phong", "blinn", "ggx", "ward"}
    with pytest.raises(PrtError, match="unknown built-in BRDF"):
        builtin_rpo("velvet")


def test_bad_files_and_factors(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="not found"):
        RPO.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PrtError, match="not an RPO file"):
        RPO.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(PrtError, match="not an RPO file"):
        RPO.load(tmp_path / "other.npz")
    rpo = build_rpo(Lambert(), order=2, k=1, n_theta=4, n_phi=8)
    with pytest.raises(PrtError, match=".npz"):
        rpo.save(tmp_path / "x.bin")
    with pytest.raises(PrtError, match=r"\(k, C\)"):
        RPO.from_factors(np.zeros((2, 9)), np.zeros((2, 4)), np.ones(3), "x", 0.0)
    with pytest.raises(PrtError, match="square"):
        RPO.from_factors(np.zeros((2, 5)), np.zeros((2, 5)), np.ones(3), "x", 0.0)
    with pytest.raises(PrtError, match="unsupported SH order"):
        build_rpo(Lambert(), order=9)
