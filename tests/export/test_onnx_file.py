"""Generic ONNX export machinery: opset, checker, metadata, dynamic batch, parity, errors."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch
from torch import nn

from prt_torch.errors import PrtError
from prt_torch.export.onnx_file import export_onnx, initializer_bytes, opset_of, read_metadata
from prt_torch.export.parity import check_parity, relative_error


class TinyMLP(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.l1 = nn.Linear(6, 16)
        self.l2 = nn.Linear(16, 10)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.l2(torch.tanh(self.l1(x))).reshape(x.shape[0], 5, 2)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[TinyMLP, object]:
    m = TinyMLP()
    path = tmp_path_factory.mktemp("onnx") / "tiny.onnx"
    export_onnx(m, [torch.randn(3, 6)], path, ["pose"], ["out"], {"pose": {0: "B"}, "out": {0: "B"}},
                metadata={"prt.sh_order": 4, "prt.note": "hello"})
    return m, path


def test_export_is_checked_opset17_with_metadata(tiny) -> None:
    m, path = tiny
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    assert opset_of(path) >= 17
    meta = read_metadata(path)
    assert meta["prt.sh_order"] == "4" and meta["prt.note"] == "hello"
    # weights: 6*16+16 + 16*10+10 floats
    assert initializer_bytes(path) >= 4 * (6 * 16 + 16 + 16 * 10 + 10)


def test_dynamic_batch_parity_and_detects_a_changed_module(tiny) -> None:
    m, path = tiny
    x = np.random.default_rng(0).normal(size=(7, 6)).astype(np.float32)
    p = check_parity(m, path, {"pose": x})
    assert p.rel_error <= 1e-5
    other = TinyMLP()
    with torch.no_grad():
        other.l2.bias += 0.1
    with pytest.raises(PrtError, match="parity failed"):
        check_parity(other, path, {"pose": x})


def test_dynamo_exporter_matches(tmp_path) -> None:
    m = TinyMLP()
    path = export_onnx(m, [torch.randn(2, 6)], tmp_path / "d.onnx", ["pose"], ["out"],
                       {"pose": {0: "B"}, "out": {0: "B"}}, exporter="dynamo", opset=18)
    assert opset_of(path) == 18
    assert check_parity(m, path, {"pose": np.ones((4, 6), np.float32)}).rel_error <= 1e-5


def test_bad_requests_raise(tmp_path) -> None:
    m = TinyMLP()
    with pytest.raises(PrtError, match="opset"):
        export_onnx(m, [torch.randn(2, 6)], tmp_path / "x.onnx", ["pose"], ["out"], opset=13)
    with pytest.raises(PrtError, match="exporter"):
        export_onnx(m, [torch.randn(2, 6)], tmp_path / "x.onnx", ["pose"], ["out"], exporter="magic")
    with pytest.raises(PrtError, match="example inputs"):
        export_onnx(m, [torch.randn(2, 6)], tmp_path / "x.onnx", ["pose", "extra"], ["out"])
    with pytest.raises(PrtError, match="not found"):
        read_metadata(tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not a protobuf at all \x00\x01")
    with pytest.raises(PrtError):
        read_metadata(tmp_path / "junk.onnx")
    assert not (tmp_path / "x.onnx").exists()  # nothing half-written


def test_relative_error_shape_mismatch() -> None:
    with pytest.raises(PrtError, match="shapes differ"):
        relative_error(np.zeros((2, 3)), np.zeros((3, 2)))
    assert relative_error(np.array([1.0, 2.0]), np.array([1.0, 4.0])).rel_error == pytest.approx(0.5)
