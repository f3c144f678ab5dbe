"""The fast SHEXP kernels against the project's plain rules: the zonal sum vs ``zh_to_sh(...).sum``, the squaring
through point values vs the Gaunt product, the run-time log (cos-uniform table, nearest row) vs the angular-radius
table with ``asin`` and linear interpolation, the per-element squaring counts, and the ONNX ``Loop`` of a
data-dependent number of squarings vs torch."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from prt_torch.sh.quadrature import random_rotations, sphere_directions
from prt_torch.sh.zonal import zh_to_sh


@pytest.mark.parametrize("order", [1, 2, 4, 6])
def test_zonal_sum_equals_the_sum_of_rotated_zonals(order: int) -> None:
    from prt_torch.shexp.zonal_sum import zonal_sum

    rng = np.random.default_rng(order)
    u = sphere_directions(3 * 7, seed=order).reshape(3, 7, 3)  # (V, S, 3)
    g = rng.normal(size=(3, 7, order))
    want = zh_to_sh(g, u).sum(-2)
    ut = torch.from_numpy(u)
    got = zonal_sum(ut[..., 0], ut[..., 1], ut[..., 2], list(torch.from_numpy(g).unbind(-1)), order).numpy()
    assert np.allclose(got, want, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("order", [2, 3, 4, 5])
def test_squaring_through_point_values_is_the_gaunt_product(order: int) -> None:
    from prt_torch.sh.product import sh_product
    from prt_torch.shexp.exponential import sh_square, square_operators

    g = np.random.default_rng(order).normal(size=(6, order * order))
    a, b = (torch.from_numpy(m.astype(np.float64)) for m in square_operators(order))
    got = sh_square(torch.from_numpy(g), a, b).numpy()
    want = sh_product(g, g)
    assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max()  # float32 operators


def _reference_log(points: np.ndarray, frames: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                   order: int) -> np.ndarray:
    """The definition in float64: asin, linear interpolation of the angular-radius table, zh_to_sh, sum."""
    from prt_torch.shexp.tables import log_visibility_table

    table = log_visibility_table(order)
    alphas = np.linspace(0.0, math.pi / 2, table.shape[0])
    d = centers[None] - points[:, None]  # (V, S, 3)
    dist = np.linalg.norm(d, axis=-1)
    a = np.arcsin(np.clip(radii[None] / dist, 0, 1))
    g = np.stack([np.interp(a, alphas, table[:, l]) for l in range(order)], -1) * (dist > radii[None])[..., None]
    u = np.einsum("vij,vsj->vsi", frames, d / dist[..., None])
    return zh_to_sh(g, u).sum(1)


def test_run_time_log_matches_the_definition() -> None:
    from prt_torch.shexp.tables import cos_log_table
    from prt_torch.shexp.visibility import log_visibility_sum

    order = 4
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 3))
    centers = rng.normal(size=(9, 3)) * 1.5
    radii = rng.uniform(0.2, 0.9, size=9)
    pts[:4] = centers[:4] + 0.05  # receivers inside spheres: those spheres contribute nothing
    frames = random_rotations(300, seed=5)
    want = _reference_log(pts, frames, centers, radii, order)
    got = log_visibility_sum(*(torch.from_numpy(x).float() for x in (pts, centers, radii)),
                             torch.from_numpy(np.array(cos_log_table(order))), order,
                             torch.from_numpy(frames).float()).numpy()
    # nearest row of 8192 uniform in cos(alpha) (tables.py); measured 2.6e-4 of the largest coefficient
    assert np.abs(got - want).max() <= 1e-3 * np.abs(want).max()


def _logs(scales: np.ndarray, order: int = 4) -> np.ndarray:
    from prt_torch.shexp.tables import log_visibility_table

    t = log_visibility_table(order)
    axes = sphere_directions(3 * len(scales), seed=2).reshape(len(scales), 3, 3)
    return zh_to_sh(np.repeat(t[300][None, None], 3, 1), axes).sum(1) * scales[:, None]


def test_each_element_gets_its_own_squaring_count() -> None:
    from prt_torch.shexp import sh_exp

    f = torch.from_numpy(_logs(np.array([0.01, 0.2, 1.0, 3.0, 8.0])))  # HYB counts 0 .. 7
    batch = sh_exp(f).numpy()
    alone = np.stack([sh_exp(f[i : i + 1]).numpy()[0] for i in range(len(f))])
    assert np.allclose(batch, alone, rtol=1e-9, atol=1e-12)


def test_onnx_loop_runs_the_batch_count_of_squarings(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from prt_torch.export.onnx_file import export_onnx
    from prt_torch.runtime.session import OrtGraph
    from prt_torch.shexp.exponential import SHExponential

    module = SHExponential(4)
    path = export_onnx(module, [torch.from_numpy(_logs(np.array([0.5, 1.0]))).float()[None]], tmp_path / "exp.onnx",
                       ("f",), ("g",), dynamic_axes={"f": {0: "B", 1: "V"}, "g": {0: "B", 1: "V"}}, metadata={})
    graph = OrtGraph(path)
    for scales in (np.array([0.01, 0.05]), np.array([0.2, 3.0, 8.0, 20.0])):  # 0 and up to 8 squarings
        f = _logs(scales).astype(np.float32)[None]
        got = graph.run({"f": f})["g"]
        want = module(torch.from_numpy(f)).numpy()
        assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()
