"""Regressors against independent implementations; model files; ONNX parity."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
from sklearn.preprocessing import PolynomialFeatures

from prt_torch.errors import PrtError
from prt_torch.models import (
    KINDS,
    MLPRegressor,
    QuadraticRegressor,
    load_metadata,
    load_model,
    load_model_file,
    quadratic_features,
)


def test_quadratic_features_match_sklearn() -> None:
    x = np.random.default_rng(0).normal(size=(7, 4))
    ours = quadratic_features(torch.as_tensor(x)).numpy()
    ref = PolynomialFeatures(degree=2, include_bias=False).fit_transform(x)
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    assert QuadraticRegressor(4, 2, 3).feature_dim == ref.shape[1]


def test_mlp_forward_is_eq12_per_cluster() -> None:
    torch.manual_seed(0)
    m = MLPRegressor(3, 4, 2, 5).double()
    for p in m.parameters():
        torch.nn.init.normal_(p)
    x = torch.randn(6, 3, dtype=torch.float64)
    got = m(x).detach().numpy()
    xs = x.numpy()
    for g in range(4):  # eq. 12 written out per cluster in numpy
        d, d0 = m.hidden_weight[g].detach().numpy(), m.hidden_bias[g].detach().numpy()
        c, c0 = m.out_weight[g].detach().numpy(), m.out_bias[g].detach().numpy()
        ref = np.stack([sum(c[:, n] * np.tanh(d[n] @ xi + d0[n]) for n in range(5)) + c0 for xi in xs])
        np.testing.assert_allclose(got[:, g], ref, atol=1e-12)


def test_load_model_roundtrip_and_metadata(small_run: Path) -> None:
    meta = load_metadata(small_run)
    assert set(meta["kinds"]) == set(KINDS)
    default = load_model(small_run)
    assert default.kind == meta["default_kind"] == "mlp"
    x = torch.randn(3, default.n_features)
    for kind in KINDS:
        m = load_model(small_run, kind)
        assert m.kind == kind and not m.training
        assert all(p.dtype == torch.float32 for p in m.state_dict().values() if p.is_floating_point())
        y = m(x)
        assert y.shape == (3, meta["n_vertices"], meta["n_coeffs"]) and y.dtype == torch.float32
    torch.testing.assert_close(default(x), load_model(small_run, "mlp")(x))


def test_model_loads_without_dataset(small_run: Path, tmp_path: Path) -> None:
    dst = tmp_path / "copy"
    shutil.copytree(small_run, dst)
    m = load_model(dst, "quadratic")
    assert torch.isfinite(m(torch.zeros(1, m.n_features))).all()


def test_onnx_parity(small_run: Path, tmp_path: Path) -> None:
    for kind in KINDS:
        m = load_model(small_run, kind)
        path = tmp_path / f"{kind}.onnx"
        torch.onnx.export(m, (torch.zeros(2, m.n_features),), str(path), input_names=["pose"],
                          output_names=["visibility"], dynamic_axes={"pose": {0: "B"}, "visibility": {0: "B"}},
                          dynamo=False)
        x = np.random.default_rng(1).normal(size=(5, m.n_features)).astype(np.float32)
        got = ort.InferenceSession(str(path)).run(None, {"pose": x})[0]
        np.testing.assert_allclose(got, m(torch.as_tensor(x)).detach().numpy(), atol=1e-4, rtol=1e-4)


def test_bad_inputs_raise(small_run: Path, tmp_path: Path) -> None:
    m = load_model(small_run)
    with pytest.raises(PrtError, match="pose features: expected shape"):
        m.predict(np.zeros((2, m.n_features + 1)))
    with pytest.raises(PrtError, match="NaN"):
        m.predict(np.full((2, m.n_features), np.nan))
    with pytest.raises(PrtError, match="run directory not found"):
        load_model(tmp_path / "nope")
    with pytest.raises(PrtError, match="unknown model kind"):
        load_model(small_run, "cubic")
    with pytest.raises(PrtError, match="no trained default model"):
        load_model(tmp_path)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(PrtError, match="not a prt_torch model file"):
        load_model_file(bad)


def test_global_output_variant_trains_loads_and_counts(synthetic_dataset: Path, tmp_path: Path) -> None:
    from prt_torch.fit.config import TrainConfig
    from prt_torch.fit.train import train_dataset
    from prt_torch.models.storage import compact_floats, state_bytes

    train_dataset(synthetic_dataset, tmp_path, TrainConfig(kinds=["linear"], output_pca="global", alphas=[1.0]))
    m = load_model(tmp_path, "linear")
    meta = load_metadata(tmp_path)
    k = m.out.basis.shape[0]
    v, c, a, d = m.n_vertices, m.n_coeffs, m.n_features, m.inp.out_dim
    assert m(torch.zeros(2, a)).shape == (2, v, c)
    assert meta["output_dims"] == [c * k]
    # packed: input PCA + per-vertex mean (V) + shared basis (k V) + weights/bias of C k outputs
    assert compact_floats(m) == a + a * d + v + k * v + (d + 1) * c * k
    assert state_bytes(m) == 4 * (a + a * d + v * c + k * v + (d + 1) * c * k)


def test_files_store_no_padding_and_default_is_a_link(small_run: Path, tmp_path: Path) -> None:
    """The saved basis holds exactly sum_g K_g V_g C numbers (counted from the cluster sizes of the
    metadata, not from the saver), the file round-trips exactly, and model.pt is the same file."""
    from prt_torch.bake.store import open_dataset
    from prt_torch.models import save_model

    meta = load_metadata(small_run)
    labels = open_dataset(meta["dataset"]).cluster
    sizes = np.bincount(labels - labels.min())
    sizes = sizes[sizes > 0] * meta["n_coeffs"]
    dims = np.asarray(meta["output_dims"])
    for kind in KINDS:
        path = small_run / "models" / f"{kind}.pt"
        payload = torch.load(path, weights_only=True)
        state = payload["state_dict"]
        assert "out.basis" not in state and state["out.basis_packed"].numel() == int((dims * sizes).sum())
        m = load_model(small_run, kind)
        assert m.out.basis.shape == (len(dims), dims.max(), sizes.max())  # re-padded in memory
        save_model(m, tmp_path / f"{kind}.pt")
        again = load_model_file(tmp_path / f"{kind}.pt")
        x = torch.randn(4, m.n_features)
        assert torch.equal(m(x), again(x))
    default = small_run / "model.pt"
    mlp = small_run / "models" / "mlp.pt"
    assert default.stat().st_ino == mlp.stat().st_ino or default.read_bytes() == mlp.read_bytes()
