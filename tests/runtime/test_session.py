"""OrtGraph: loading, input validation (one-line PrtError), and results equal to plain onnxruntime."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from prt_torch.errors import PrtError
from prt_torch.runtime.session import OrtGraph
from tests.tolerance import assert_bitwise


@pytest.fixture(scope="module")
def matmul_onnx(tmp_path_factory):
    """A hand-built graph y = x @ W (x: (B, 4), W: (4, 3)) with a metadata property, written by onnx."""
    w = np.arange(12, dtype=np.float32).reshape(4, 3) / 7.0
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["x", "W"], ["y"]), helper.make_node("Add", ["y", "b"], ["out"])],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["B", 4]),
         helper.make_tensor_value_info("b", TensorProto.FLOAT, ["B", 3])],
        [helper.make_tensor_value_info("out", TensorProto.FLOAT, ["B", 3])],
        [helper.make_tensor("W", TensorProto.FLOAT, [4, 3], w.ravel())],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.metadata_props.add(key="prt.n_vertices", value="5")
    path = tmp_path_factory.mktemp("ort") / "mm.onnx"
    onnx.save(model, str(path))
    return path, w


def test_run_matches_numpy_and_reads_metadata(matmul_onnx) -> None:
    path, w = matmul_onnx
    g = OrtGraph(path)
    assert g.metadata["prt.n_vertices"] == "5"
    assert g.inputs == {"x": ("B", 4), "b": ("B", 3)}
    x = np.random.default_rng(0).normal(size=(6, 4))
    b = np.ones((6, 3))
    out = g.run({"x": x, "b": b})["out"]
    np.testing.assert_allclose(out, x @ w + 1, rtol=1e-5, atol=1e-5)
    fast = g.run_unchecked({"x": x.astype(np.float32), "b": b.astype(np.float32)})[0]
    assert_bitwise(fast, out,
                   why='the same graph and session on the same float32 values (the checked path casts them first)')


def test_bad_inputs_raise_one_line_errors(matmul_onnx) -> None:
    path, _ = matmul_onnx
    g = OrtGraph(path)
    ok = {"x": np.zeros((2, 4)), "b": np.zeros((2, 3))}
    cases = [
        ({"x": np.zeros((2, 5)), "b": ok["b"]}, "axis 1 must be 4"),
        ({"x": np.zeros((2, 4, 1)), "b": ok["b"]}, "must have 2 dims"),
        ({"x": np.zeros((3, 4)), "b": ok["b"]}, "axis 'B' is"),
        ({"x": np.full((2, 4), np.nan), "b": ok["b"]}, "NaN"),
        ({"x": ok["x"]}, "missing input"),
        ({**ok, "z": ok["x"]}, "unknown input"),
    ]
    for feeds, msg in cases:
        with pytest.raises(PrtError, match=msg) as exc:
            g.run(feeds)
        assert "\n" not in str(exc.value)


def test_missing_and_corrupt_files(tmp_path) -> None:
    with pytest.raises(PrtError, match="not found"):
        OrtGraph(tmp_path / "nope.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"garbage")
    with pytest.raises(PrtError, match="cannot load"):
        OrtGraph(bad)


def test_devices(matmul_onnx) -> None:
    """CPU always; an unknown device or CUDA without onnxruntime-gpu is a one-line PrtError."""
    from prt_torch.runtime.session import cuda_available, providers_for

    path, w = matmul_onnx
    assert providers_for("cpu") == ["CPUExecutionProvider"]
    with pytest.raises(PrtError, match="unknown device"):
        OrtGraph(path, device="tpu")
    if not cuda_available():
        with pytest.raises(PrtError, match="onnxruntime-gpu"):
            OrtGraph(path, device="cuda")


def test_cuda_matches_numpy(matmul_onnx) -> None:
    from prt_torch.runtime.session import cuda_available

    path, w = matmul_onnx
    if not cuda_available():
        pytest.skip("no onnxruntime CUDA provider here (needs onnxruntime-gpu and a GPU)")
    try:
        g = OrtGraph(path, device="cuda")
    except PrtError as exc:
        pytest.skip(f"CUDA provider present but unusable: {exc}")
    c = OrtGraph(path)
    feeds = {n: np.random.default_rng(0).standard_normal([d if isinstance(d, int) else 3 for d in s])
             .astype(np.float32) for n, s in c.inputs.items()}
    np.testing.assert_allclose(g.run(feeds)["out"], feeds["x"] @ w + feeds["b"], rtol=1e-4, atol=1e-5)


def test_ort_threads_are_capped_by_the_environment(matmul_onnx, monkeypatch) -> None:
    from prt_torch.runtime.session import THREADS_ENV, session_threads

    path, _ = matmul_onnx
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert session_threads(2) == 2 and OrtGraph(path, threads=2).threads == 2
    monkeypatch.setenv(THREADS_ENV, "1")
    assert session_threads(2) == 1 and OrtGraph(path, threads=2).threads == 1
    monkeypatch.setenv(THREADS_ENV, "4")
    assert session_threads(2) == 2  # a cap, never more than the caller asked for
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(PrtError, match=THREADS_ENV):
            session_threads(2)
