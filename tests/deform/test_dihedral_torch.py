"""The torch / ONNX dihedral angles (the exported graph's pre-processing) vs the numpy rule."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.deform.dihedral import dihedral_angles
from prt_torch.deform.dihedral_torch import DihedralAngles, atan2
from prt_torch.deform.mesh import interior_edges
from tests.deform.sheets import sheet


def test_atan2_from_atan_matches_math_atan2() -> None:
    vals = [0.0, 1e-30, -1e-30, 0.3, -0.3, 1.0, -1.0, 7.0, -7.0, 1e8, -1e8]
    y, x = np.meshgrid(vals, vals, indexing="ij")
    got = atan2(torch.tensor(y.ravel()), torch.tensor(x.ravel())).numpy()
    ref = np.array([math.atan2(a, b) for a, b in zip(y.ravel(), x.ravel(), strict=True)])
    ref[ref <= -math.pi] = math.pi  # our interval is (-pi, pi]
    np.testing.assert_allclose(got, ref, atol=1e-15)
    assert atan2(torch.tensor([0.0]), torch.tensor([0.0])).item() == 0.0
    assert atan2(torch.tensor([-0.0]), torch.tensor([-2.0])).item() == pytest.approx(math.pi)


def _bent_positions(batch: int) -> tuple[np.ndarray, np.ndarray]:
    v, f = sheet(12, 10)
    rng = np.random.default_rng(5)
    x = v[None] + rng.normal(scale=[0.02, 0.02, 0.15], size=(batch, *v.shape))
    return x.astype(np.float32), interior_edges(f)


def test_torch_module_matches_numpy() -> None:
    x, e = _bent_positions(3)
    mod = DihedralAngles(e)
    got = mod(torch.from_numpy(x)).numpy()
    ref = dihedral_angles(x.astype(np.float64), e)
    keep = np.abs(ref) < np.pi - 1e-3
    assert keep.mean() > 0.99 and got.dtype == np.float32
    np.testing.assert_allclose(got[keep], ref[keep], atol=1e-5)
    got64 = mod(torch.from_numpy(x.astype(np.float64))).numpy()
    np.testing.assert_allclose(got64, ref, atol=1e-12)


def test_onnx_export_matches_numpy(tmp_path) -> None:
    import onnx
    import onnxruntime as ort

    from prt_torch.export.onnx_file import export_onnx

    x, e = _bent_positions(4)
    path = export_onnx(DihedralAngles(e), [torch.from_numpy(x[:2])], tmp_path / "dihedral.onnx", ["positions"],
                       ["angles"], dynamic_axes={"positions": {0: "B"}, "angles": {0: "B"}})
    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert "Atan" in ops and "Atan2" not in ops
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = sess.run(["angles"], {"positions": x})[0]  # another batch size than the traced one
    ref = dihedral_angles(x.astype(np.float64), e)
    keep = np.abs(ref) < np.pi - 1e-3
    assert got.shape == ref.shape and keep.mean() > 0.99
    np.testing.assert_allclose(got[keep], ref[keep], atol=1e-5)
