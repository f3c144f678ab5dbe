"""Where the fit runs (``train.device``, :mod:`prt_torch.fit.device`).

* resolution: ``auto`` follows ``torch.cuda.is_available()``; ``cuda`` without a GPU and unknown values fail
  with one line (config and CLI);
* the CPU is the reference path: ``device: cpu`` and ``auto`` without a GPU write bit-identical models (every
  tensor) and keep the pre-existing ``train`` stage key (the settings without ``device``), so existing runs do
  not refit;
* the device-generic torch path (what CUDA runs) agrees with the reference on the CPU; and on CUDA, when a GPU
  is present. Tolerances (float64 fits): ridge weights within 1e-9 of the largest weight; the MLP's final
  objective within 1e-8 relative (L-BFGS follows the rounding-perturbed path: measured 1e-12 on the CPU torch
  path) and the float32 models' predictions within 1e-5 of the largest prediction.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from prt_torch.bake.store import open_dataset
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.fit.config import TrainConfig
from prt_torch.fit.device import fit_device, resolve_device
from prt_torch.fit.inputs import JointInputs
from prt_torch.fit.kinds import FitResult, Reduced, fit_mlp_kind, fit_ridge_kind, reduce_training
from prt_torch.fit.mlp import MLPObjective, MLPParams, reference_objective
from prt_torch.fit.train import train_dataset, train_key
from prt_torch.rundir import stage_key

SMALL = dict(alphas=[1e-2, 1.0], mlp_alphas=[0.1, 1.0], neurons=[4, 6], cv_iter=15, max_iter=30)
NO_GPU = "no CUDA GPU here: the CUDA == CPU fit parity needs one"


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.fixtures_run import write_synthetic_dataset

    return write_synthetic_dataset(tmp_path_factory.mktemp("device") / "dataset.zarr", n_vertices=120, order=3,
                                   frames_per_clip=24)


@pytest.fixture(scope="module")
def reduced(tiny_dataset: Path) -> dict[str, Reduced]:
    """The tiny dataset reduced, with the shared PCA inputs and with a per-cluster input selection."""
    info = open_dataset(tiny_dataset)
    cfg = TrainConfig(**SMALL)
    plain = reduce_training(info.split("train"), info.cluster, cfg)
    sel = reduce_training(info.split("train"), info.cluster, cfg)
    d = sel.x.shape[1]
    mask = np.random.default_rng(0).random((sel.z.shape[1], d)) < 0.6
    mask[:, 0] = True
    sel.sel = JointInputs(mean=sel.inp.mean, proj=sel.inp.components.T / sel.inp.scale[None, :], mask=mask,
                          live=np.arange(d))
    sel.xs = sel.x
    return {"pca": plain, "selected": sel}


def _one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and len(msg) < 300, msg
    return msg


def test_resolution(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu" and fit_device("auto") is None and fit_device("cpu") is None
    with pytest.raises(PrtError) as exc:
        resolve_device("cuda")
    assert "cuda" in _one_line(exc)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == "cuda" and fit_device("auto") == torch.device("cuda")
    assert resolve_device("cpu") == "cpu"
    with pytest.raises(PrtError) as exc:
        resolve_device("gpu")
    assert "gpu" in _one_line(exc)


def test_bad_value_is_a_config_error() -> None:
    with pytest.raises(ValidationError):
        TrainConfig(device="gpu")
    with pytest.raises(PrtError) as exc:
        config_from_dict({"name": "x", "character": {}, "train": {"device": "gpu"}})
    assert "train.device" in _one_line(exc)
    assert config_from_dict({"name": "x", "character": {}}).train.device == "auto"


def test_cli_device_flag(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from prt_torch.cli import main

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    config = str(Path(__file__).resolve().parents[2] / "configs" / "builtin.yaml")
    for argv, word in ((["train", config, "--device", "gpu"], "gpu"), (["train", config, "--device", "cuda"], "cuda"),
                       (["bench", "fit", "--device", "cpu,tpu"], "tpu")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err and word in err, err


class _Dataset:
    """What ``train_key`` reads of a dataset."""

    def key(self) -> str:
        return "dataset-key"


def test_stage_key_unchanged_on_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    """The key of a CPU fit is the key of the same settings without ``device`` (the pre-existing key)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cfg = TrainConfig(**SMALL)
    settings = cfg.model_dump(mode="json")
    del settings["device"]
    for opt in ("transfer", "s001", "local", "peaks", "output_max_components", "input_max_components"):  # if set
        if settings.get(opt) is None:
            settings.pop(opt, None)
    old = stage_key({"train": settings, "dataset": "dataset-key"})
    assert train_key(_Dataset(), cfg) == old
    assert train_key(_Dataset(), cfg.model_copy(update={"device": "cpu"})) == old
    with pytest.raises(PrtError):
        train_key(_Dataset(), cfg.model_copy(update={"device": "cuda"}))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)  # auto now means cuda: keyed apart
    cuda = train_key(_Dataset(), cfg)
    assert cuda != old and cuda == train_key(_Dataset(), cfg.model_copy(update={"device": "cuda"}))
    assert train_key(_Dataset(), cfg.model_copy(update={"device": "cpu"})) == old


def test_cpu_fit_is_the_default_fit_bit_for_bit(tiny_dataset: Path, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``device: cpu`` and the default (``auto`` on a machine without a GPU) write the same models, bit for bit
    (every tensor of every model file; the files' zip member names carry the temporary file's name)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    runs = {}
    for name, extra in (("default", {}), ("cpu", {"device": "cpu"})):
        train_dataset(tiny_dataset, tmp_path / name, TrainConfig(**SMALL, **extra))
        runs[name] = {p.name: torch.load(p, weights_only=True) for p in (tmp_path / name / "models").glob("*.pt")}
    assert sorted(runs["cpu"]) == sorted(runs["default"]) == ["linear.pt", "mlp.pt", "quadratic.pt"]
    for file, payload in runs["cpu"].items():
        other = runs["default"][file]
        assert {k: v for k, v in payload.items() if k != "state_dict"} == \
            {k: v for k, v in other.items() if k != "state_dict"}, file
        assert payload["state_dict"].keys() == other["state_dict"].keys(), file
        for key, t in payload["state_dict"].items():
            assert t.dtype == other["state_dict"][key].dtype and torch.equal(t, other["state_dict"][key]), (file, key)


def _params(r: FitResult) -> dict[str, torch.Tensor]:
    return {k: v.detach().double() for k, v in r.model.regressor.state_dict().items()}


def _assert_parity(ref: dict[str, FitResult], dev: dict[str, FitResult], pose: np.ndarray) -> None:
    for kind in ("linear", "quadratic"):
        a, b = _params(ref[kind]), _params(dev[kind])
        assert ref[kind].choice["alpha"] == dev[kind].choice["alpha"], kind
        scale = max(float(t.abs().max()) for t in a.values())
        # the model is float32: compare at its precision, relative to the largest weight
        for n in a:
            assert float((a[n] - b[n]).abs().max()) <= 1e-9 * scale + 2 ** -23 * float(a[n].abs().max()), (kind, n)
    m_ref, m_dev = ref["mlp"], dev["mlp"]
    assert m_ref.choice["neurons"] == m_dev.choice["neurons"] and m_ref.choice["alpha"] == m_dev.choice["alpha"]
    o_ref, o_dev = m_ref.choice["objective"], m_dev.choice["objective"]
    assert abs(o_ref - o_dev) <= 1e-8 * abs(o_ref), (o_ref, o_dev)
    for kind in ("linear", "quadratic", "mlp"):
        assert all(p.device.type == "cpu" for p in dev[kind].model.parameters())
        pa, pb = ref[kind].model.predict(pose), dev[kind].model.predict(pose)
        assert float((pa - pb).abs().max()) <= 1e-5 * float(pa.abs().max()), kind


def _fit_all(red: Reduced, device: torch.device | None) -> dict[str, FitResult]:
    cfg = TrainConfig(**SMALL)
    out = {k: fit_ridge_kind(k, red, cfg.alphas, device=device) for k in ("linear", "quadratic")}
    out["mlp"] = fit_mlp_kind(red, cfg, device=device)
    return out


@pytest.mark.parametrize("inputs", ["pca", "selected"])
def test_torch_path_matches_reference_on_cpu(reduced: dict[str, Reduced], tiny_dataset: Path, inputs: str) -> None:
    """The device-generic path (tensors, torch SVD) run on the CPU against the numpy reference path."""
    red = reduced[inputs]
    pose = open_dataset(tiny_dataset).split("heldout").pose
    _assert_parity(_fit_all(red, None), _fit_all(red, torch.device("cpu")), pose)


def test_objective_device_branch_matches_autograd() -> None:
    """The objective's non-CPU branch (torch tanh into the strided activation buffer, block terms summed as
    tensors, one host sync) on the CPU: value and gradient against autograd of :func:`reference_objective`."""
    from tests.fit.test_mlp_grad import _problem

    pb = _problem(seed=5)
    obj = MLPObjective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"],
                       pb["input_mask"], block_cost=0.0)
    assert len(obj.blocks) > 1
    for b in obj.blocks:
        b.on_cpu = False
    theta = obj.pack(pb["p"])
    grad = torch.full_like(theta, float("nan"))
    loss = obj(theta, grad)
    assert isinstance(loss, float) and obj(theta) == loss
    free = [t.clone().requires_grad_(True) for t in (pb["p"].D, pb["p"].d0, pb["p"].C, pb["p"].c0)]
    masked = MLPParams(*(t * m for t, m in zip(free, pb["masks"], strict=True)))
    ref = reference_objective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], masked)
    ref_grad = torch.autograd.grad(ref, free)
    assert abs(loss - ref.item()) <= 1e-12 * abs(ref.item())
    got = obj.unpack(grad)
    for a, b in zip((got.D, got.d0, got.C, got.c0), ref_grad, strict=True):
        assert float((a - b).abs().max()) <= 1e-10 * max(1.0, float(b.abs().max()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_GPU)
@pytest.mark.parametrize("inputs", ["pca", "selected"])
def test_cuda_matches_cpu(reduced: dict[str, Reduced], tiny_dataset: Path, inputs: str) -> None:
    red = reduced[inputs]
    pose = open_dataset(tiny_dataset).split("heldout").pose
    _assert_parity(_fit_all(red, None), _fit_all(red, torch.device("cuda")), pose)
