"""The shading SH products (outer + GEMM, padded gathers) vs the reference sh_product, and prt bench shade."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from prt_torch.cli import main
from prt_torch.sh.product import sh_product
from prt_torch.shade.triple_product import gather_product, gaunt_flat, gaunt_gather_tensors, outer_product_sh


@pytest.mark.parametrize("order", [2, 4, 5])
def test_products_match_reference(order: int) -> None:
    c = order * order
    rng = np.random.default_rng(order)
    a, b = rng.normal(size=(3, 7, c)), rng.normal(size=(3, 7, c))
    ref = sh_product(a, b)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    got = outer_product_sh(ta, tb, torch.from_numpy(gaunt_flat(order).copy()))
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-12)
    got = gather_product(ta, tb, *gaunt_gather_tensors(order, torch.float64))
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-12)


def test_bench_shade_smoke(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "shade", "--vertices", "64", "--repeat", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["seconds"]) == {"matrix", "product", "fused", "fused_gather", "dense", "lobes"}
    assert max(out["max_rel_diff_to_fused"].values()) < 1e-5  # all orders compute the same radiance
    assert main(["bench", "shade", "--order", "1"]) == 2
