"""Learned transfer (prt_torch.transfer.fit): exact recovery, the reductions vs scikit-learn, the MLP, bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from prt_torch.bake.store import SplitData
from prt_torch.errors import PrtError
from prt_torch.fit.config import TrainConfig, TransferConfig
from prt_torch.transfer.fit import check_target, fit_transfer, reduce_transfer, transfer_rel_err

F, A, V, ORDER = 48, 6, 30, 3
C = ORDER * ORDER


def _split(pose: np.ndarray) -> SplitData:
    f = pose.shape[0]
    clip = (np.arange(f) >= f // 2).astype(np.int32)
    idx = np.where(clip == 0, np.arange(f), np.arange(f) - f // 2).astype(np.int32)
    return SplitData("train", pose.astype(np.float32), np.zeros((f, V, 4), np.float32), clip, idx, ["a", "b"],
                     np.arange(f))


@pytest.fixture(scope="module")
def data() -> dict[str, np.ndarray]:
    """Poses ``(F + 20, A)`` and a transfer that is an affine function of the pose ``(F + 20, V, C)``."""
    rng = np.random.default_rng(0)
    pose = rng.normal(size=(F + 20, A))
    w = rng.normal(size=(A, V * C)) * 0.1
    mean = rng.normal(size=V * C)
    t = (mean + pose @ w).reshape(-1, V, C)
    return {"pose": pose, "t": t, "noisy": t + 0.05 * rng.normal(size=t.shape)}


CFG = TrainConfig(kinds=["linear"], folds=2, alphas=[1e-3, 1e-1, 10.0], threads=1)


def test_linear_recovers_pose_linear_transfer(data: dict[str, np.ndarray]) -> None:
    """Every input and output dimension kept, alpha 0: the ridge model is the least-squares map, so it reproduces
    an exactly pose-linear transfer on unseen poses and agrees with numpy's lstsq on the unreduced problem."""
    tc = TransferConfig(kinds=["linear"], input_components=A, output_components=None, output_variance=1.0,
                        output_pca="global", alpha=0.0)
    tr = _split(data["pose"][:F])
    red = reduce_transfer(tr, data["t"][:F], np.zeros(V, np.int32), tc, CFG)
    model = fit_transfer(red, tc, CFG)["linear"].model
    test = data["pose"][F:]
    pred = model.predict(test).numpy()
    assert pred.shape == (20, V, C)
    x1 = np.hstack([data["pose"][:F], np.ones((F, 1))])
    coef = np.linalg.lstsq(x1, data["t"][:F].reshape(F, -1), rcond=None)[0]
    ref = (np.hstack([test, np.ones((20, 1))]) @ coef).reshape(20, V, C)
    assert transfer_rel_err(pred, data["t"][F:]) < 1e-5
    assert transfer_rel_err(pred, ref) < 1e-5


def _sk_fit(pose: np.ndarray, t: np.ndarray, test: np.ndarray, k_in: int, k_out: int, alpha: float,
            groups: list[np.ndarray] | None) -> np.ndarray:
    """scikit-learn: pose PCA, output PCA (global rows ``t[f, :, c]``, or per group over the flattened
    ``(V_g * C)`` vectors), Ridge, inverse transform."""
    from sklearn.decomposition import PCA
    from sklearn.linear_model import Ridge

    ip = PCA(k_in, svd_solver="full").fit(pose)
    x, xt = ip.transform(pose), ip.transform(test)
    f, n = t.shape[0], test.shape[0]
    if groups is None:
        rows = np.transpose(t, (0, 2, 1)).reshape(f * C, V)
        op = PCA(k_out, svd_solver="full").fit(rows)
        z = op.transform(rows).reshape(f, C * k_out)
        zt = Ridge(alpha=alpha).fit(x, z).predict(xt).reshape(n * C, k_out)
        return np.transpose(op.inverse_transform(zt).reshape(n, C, V), (0, 2, 1))
    out = np.zeros((n, V, C))
    for m in groups:
        op = PCA(k_out, svd_solver="full").fit(t[:, m].reshape(f, -1))
        zt = Ridge(alpha=alpha).fit(x, op.transform(t[:, m].reshape(f, -1))).predict(xt)
        out[:, m] = op.inverse_transform(zt).reshape(n, len(m), C)
    return out


@pytest.mark.parametrize("output_pca", ["global", "cluster"])
def test_reduced_ridge_matches_sklearn(data: dict[str, np.ndarray], output_pca: str) -> None:
    """PCA(3, 4) + ridge on noisy data equals scikit-learn's PCA + Ridge (a second implementation)."""
    cluster = (np.arange(V) >= 12).astype(np.int32)
    tc = TransferConfig(kinds=["linear"], input_components=3, output_components=4, output_pca=output_pca,
                        alpha=0.7)
    tr = _split(data["pose"][:F])
    red = reduce_transfer(tr, data["noisy"][:F], cluster, tc, CFG)
    assert red.inp.n_components == 3 and list(red.out.dims) == ([4 * C] if output_pca == "global" else [4, 4])
    pred = fit_transfer(red, tc, CFG)["linear"].model.predict(data["pose"][F:]).numpy()
    groups = None if output_pca == "global" else [np.flatnonzero(cluster == g) for g in (0, 1)]
    ref = _sk_fit(data["pose"][:F], data["noisy"][:F], data["pose"][F:], 3, 4, 0.7, groups)
    assert transfer_rel_err(pred, ref) < 1e-5


def test_mlp_and_cv_fit_a_smooth_transfer(data: dict[str, np.ndarray]) -> None:
    """The tanh MLP (L-BFGS, per-cluster CV) and the CV-chosen ridge both learn a pose-linear transfer: held-out
    error far below the training-mean predictor's."""
    cfg = CFG.model_copy(update={"neurons": [8], "mlp_alphas": [0.01], "max_iter": 100, "cv_iter": 20})
    tc = TransferConfig(kinds=["linear", "mlp"], input_components=A, output_components=6, output_pca="cluster")
    tr = _split(data["pose"][:F])
    red = reduce_transfer(tr, data["t"][:F], (np.arange(V) % 3).astype(np.int32), tc, cfg)
    fits = fit_transfer(red, tc, cfg)
    assert list(fits) == ["linear", "mlp"]
    truth = data["t"][F:]
    base = transfer_rel_err(np.broadcast_to(data["t"][:F].mean(0), truth.shape), truth)
    for kind, r in fits.items():
        assert transfer_rel_err(r.model.predict(data["pose"][F:]).numpy(), truth) < 0.1 * base, kind
    assert fits["linear"].choice["alpha"] and "cv_error" in fits["linear"].choice


def test_bad_input_one_line_errors(data: dict[str, np.ndarray], synthetic_dataset: Path, tmp_path: Path) -> None:
    bad = data["t"][:F].copy()
    bad[0, 0, 0] = np.nan
    for y, word in ((bad, "NaN"), (data["t"][:5], "expected a (48, V, C)"), (data["t"][:F, :, :5], "order**2")):
        with pytest.raises(PrtError, match=re.escape(word)) as e:
            check_target(y, F)
        assert "\n" not in str(e.value)
    for bad_cfg in ({"kinds": ["cubic"]}, {"kinds": []}, {"output_pca": "local"}, {"input_components": 0},
                    {"alpha": -1.0}, {"extra": 1}):
        with pytest.raises(ValidationError):
            TransferConfig(**bad_cfg)
    from prt_torch.bake.store import open_dataset
    from prt_torch.fit.train import train_dataset

    cfg = TrainConfig(kinds=["linear"], threads=1, transfer=TransferConfig())
    with pytest.raises(PrtError, match="bake.transfer: true") as e:
        train_dataset(open_dataset(synthetic_dataset), tmp_path / "run", cfg)
    assert "\n" not in str(e.value)
