"""``learned_transfer``: a tiny baked run with transfer (1 bounce) trained with ``train.transfer``; onnxruntime vs
torch; the shading ``L . t`` vs the closed-form irradiance (Ramamoorthi-Hanrahan 2001); ``prt compare``; errors."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.rundir import RunDir

TINY = {
    "name": "tiny_transfer",
    "character": {"source": "builtin", "density": 0.06, "fps": 5.0, "train_clips": ["stretch"], "random_poses": 16,
                  "heldout_clips": ["wave"], "seed": 0},
    "bake": {"order": 3, "n_rays": 64, "frames_per_task": 8, "seed": 0, "transfer": True, "transfer_order": 3,
             "bounces": 1, "subsurface": {}},
    "train": {"kinds": ["linear"], "folds": 2, "alphas": [0.01, 1.0], "threads": 1,
              "transfer": {"kinds": ["linear", "mlp"], "input_components": 6, "output_components": 8,
                           "output_pca": "cluster"},
              "neurons": [4], "mlp_alphas": [1.0], "cv_iter": 10, "max_iter": 60},
}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from prt_torch.bake.runner import bake
    from prt_torch.config import config_from_dict
    from prt_torch.fit.train import train

    run_dir = tmp_path_factory.mktemp("ltransfer") / "run"
    cfg = config_from_dict({**TINY, "run_dir": str(run_dir)})
    bake(cfg, workers=1, progress=False)
    train(cfg)
    return run_dir


def test_train_writes_transfer_models(tiny_run: Path) -> None:
    """``transfer.json`` lists both kinds of both baked arrays (``transfer``, ``subsurface``) with hashes; the
    held-out errors it records are those of the saved models recomputed here, and beat the training mean."""
    from prt_torch.bake.store import open_dataset
    from prt_torch.models import load_model_file

    run = RunDir(tiny_run)
    meta = run.transfer_meta()
    assert meta["kinds"] == ["linear", "mlp"] and meta["bake"]["bounces"] == 1
    assert sorted(meta["arrays"]) == ["subsurface", "transfer"]
    ds = open_dataset(run.dataset_path)
    held = ds.split("heldout", extra=("transfer", "subsurface"))
    train = ds.split("train", extra=("transfer", "subsurface"))
    for array, arr in meta["arrays"].items():
        assert arr["n_coeffs"] == 9 and arr["reduced_inputs"] == 6 and max(arr["output_dims"]) <= 8
        metrics = json.loads(run.metrics_json.read_text())["transfer"][array]
        t = held.extra[array]
        base = np.sqrt(((t - train.extra[array].mean(0)) ** 2).sum() / (t**2).sum())
        for kind in ("linear", "mlp"):
            pred = load_model_file(run.transfer_model_path(kind, array)).predict(held.pose).numpy()
            err = np.sqrt(((pred - t) ** 2).sum() / (t**2).sum())
            assert metrics[kind]["heldout"] == pytest.approx(err, rel=1e-5)
            assert err < base, (array, kind)
    assert run.model_meta()["kinds"] == ["linear"]


def _closed_form_irradiance(normals: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Ramamoorthi & Hanrahan 2001: ``E(n) = sum_lm A_l L_lm y_lm(n)``, ``A = (pi, 2 pi / 3, pi / 4)``."""
    from prt_torch.sh.basis import band_of, sh_basis

    a = np.array([np.pi, 2 * np.pi / 3, np.pi / 4])[band_of(3)]
    return sh_basis(normals, 3) @ (a[:, None] * light)


def test_shading_matches_closed_form_irradiance() -> None:
    """``transfer_radiance`` of unoccluded transfer vectors ``int max(n.w, 0)/pi y(w) dw`` (numerical quadrature on
    a dense spherical-Fibonacci set) is ``albedo * E(n) / pi`` of the closed-form irradiance."""
    from prt_torch.compare.methods.learned_transfer import transfer_radiance
    from prt_torch.sh.basis import sh_basis

    rng = np.random.default_rng(1)
    n = 200_000
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    w = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    normals = rng.normal(size=(7, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cos = np.maximum(normals @ w.T, 0) / np.pi  # (7, n)
    t = (cos @ sh_basis(w, 3)) * (4 * np.pi / n)  # (7, 9)
    light = rng.normal(size=(16, 3))  # order 4 lighting: only its first 9 coefficients meet t
    albedo = {"lambert": np.array([0.5, 0.7, 0.9]), "phong": np.ones(3)}
    out = transfer_radiance(t[None], light, albedo)
    ref = _closed_form_irradiance(normals, light[:9]) / np.pi
    for b, a in albedo.items():
        np.testing.assert_allclose(out[b][0], a * ref, rtol=1e-3, atol=1e-4)


def _compare_run(run_dir: Path) -> Any:
    from prt_torch.compare.run import load_compare_run

    return load_compare_run(run_dir, threads=1)


def test_onnxruntime_matches_torch_and_compare(tiny_run: Path) -> None:
    """The exported graph (transfer + L . t) through onnxruntime equals the torch model and numpy shading; then
    ``prt compare`` with ``learned_transfer`` and ``baked_transfer`` reports radiance scores and the transfer error
    of the compared frames (recomputed here)."""
    import torch

    from prt_torch.compare import run_compare
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import heldout_frames
    from prt_torch.models import load_model_file

    ctx = _compare_run(tiny_run)
    assert METHODS["learned_transfer"].available(ctx) and METHODS["learned_transfer_linear"].available(ctx)
    assert not METHODS["learned_transfer_quadratic"].available(ctx)
    fs = heldout_frames(ctx, 4)
    m = METHODS["learned_transfer"]()
    m.prepare(ctx, fs)
    light = np.random.default_rng(2).normal(size=(ctx.order**2, 3)).astype(np.float32)
    t_ort, r_ort = m._run(fs.features, light)
    with torch.no_grad():
        t_torch = load_model_file(RunDir(tiny_run).transfer_model_path("mlp"))(torch.from_numpy(fs.features)).numpy()
    np.testing.assert_allclose(t_ort, t_torch, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(r_ort, t_torch @ light, rtol=1e-4, atol=1e-5)

    res = run_compare(tiny_run, methods=["learned_transfer", "baked_transfer"], max_frames=3, image_frames=1,
                      reference_frames=0, threads=1)
    lt = res["methods"]["learned_transfer"]
    assert lt["output"] == "radiance" and lt["vis_rel_err"] is None and lt["kind"] == "mlp" and lt["bytes"] > 0
    assert np.isfinite(lt["psnr_image_diffuse"]) and np.isfinite(res["methods"]["baked_transfer"]["psnr_image_diffuse"])
    fs3 = heldout_frames(ctx, 3)
    truth = ctx.dataset.rows(fs3.rows, ("transfer",))["transfer"]
    pred = m._run(fs3.features, light)[0]
    assert lt["transfer_rel_err"] == pytest.approx(np.sqrt(((pred - truth) ** 2).sum() / (truth**2).sum()), rel=1e-4)


def test_unavailable_and_bad_input(tiny_run: Path, tmp_path: Path) -> None:
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.methods.learned_transfer import transfer_radiance

    bare = SimpleNamespace(run=RunDir(tmp_path))  # no transfer.json: not available
    assert not METHODS["learned_transfer"].available(bare)
    with pytest.raises(PrtError, match="train.transfer") as e:
        RunDir(tmp_path).transfer_meta()
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="transfer_radiance") as e:
        transfer_radiance(np.zeros((2, 9)), np.zeros((9, 3)), {})
    assert "\n" not in str(e.value)
    # a transfer model file that is not the one transfer.json records: refused with one line
    run = RunDir(tiny_run)
    path = run.transfer_model_path("linear")
    data = path.read_bytes()
    try:
        path.write_bytes(data + b"x")
        with pytest.raises(PrtError, match="sha256") as e:
            run.transfer_meta()
        assert "\n" not in str(e.value)
        assert not METHODS["learned_transfer_linear"].available(_compare_run(tiny_run))
    finally:
        path.write_bytes(data)
