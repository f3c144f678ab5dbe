"""``learned_transfer``: a tiny baked run with transfer (1 bounce) and subsurface trained with ``train.transfer``;
onnxruntime vs torch; the shading ``L . t`` vs the closed-form irradiance (Ramamoorthi-Hanrahan 2001); the
subsurface term vs numpy on the baked arrays; ``prt export``'s transfer graph and ``prt play --renderer transfer``
(the same run, exported once); ``prt compare``; errors."""

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
    from prt_torch.sh.basis import sh_basis
    from prt_torch.transfer.compare import transfer_radiance

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
    t_ort, r_ort = m._run(fs.features, light)[:2]  # (transfer, L . t); then subsurface, L . t_sss
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
    from prt_torch.transfer.compare import transfer_radiance

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


# -- issue 12 item 6: the subsurface term, the exported graph, the player ----------------------------------------------


def _numpy_colour(lt: np.ndarray, lsss: np.ndarray | None, tint: np.ndarray) -> np.ndarray:
    """The documented rule written out: ``tint * (L . t) + tint / mean(tint) * (L . t_sss)``."""
    tint = np.asarray(tint, np.float64)
    out = tint * lt
    return out if lsss is None else out + (tint / tint.mean()) * lsss


def test_baked_transfer_subsurface_term_matches_numpy(tiny_run: Path) -> None:
    """``baked_transfer`` (and :func:`transfer_radiance`) on the held-out frames = numpy on the store's own
    ``transfer`` and ``subsurface`` arrays (read with zarr), float64 dot products with the lighting's first C6
    coefficients; the subsurface term is present (the store has it) and not negligible."""
    import zarr

    from prt_torch.compare.methods import METHODS, FrameBatch, RadianceRequest
    from prt_torch.compare.run import heldout_frames

    ctx = _compare_run(tiny_run)
    fs = heldout_frames(ctx, 3)
    m = METHODS["baked_transfer"]()
    m.prepare(ctx, fs)
    assert m.info()["arrays"] == ["transfer", "subsurface"]
    light = np.random.default_rng(3).normal(size=(16, 3))  # order 4: only the first 9 meet the order-3 transfer
    tints = {"a": np.array([0.8, 0.5, 0.3]), "b": np.array([0.2, 0.2, 0.2])}
    rpos = {k: SimpleNamespace(tint=v) for k, v in tints.items()}
    req = RadianceRequest(lighting=SimpleNamespace(sh=light), rpos=rpos, brdfs={}, eye=np.zeros(3))
    got = m.radiance(FrameBatch(index=np.arange(len(fs.rows)), features=fs.features, positions=None, frames=None),
                     req)
    root = zarr.open_group(str(RunDir(tiny_run).dataset_path), mode="r")
    t = np.asarray(root["transfer"][:])[fs.rows].astype(np.float64)
    sss = np.asarray(root["subsurface"][:])[fs.rows].astype(np.float64)
    lt, ls = t @ light[:9], sss @ light[:9]
    assert np.abs(ls).max() > 1e-3 * np.abs(lt).max()
    for k, tint in tints.items():
        np.testing.assert_allclose(got[k], _numpy_colour(lt, ls, tint), rtol=1e-4, atol=1e-5)
    # a grey tint keeps the baked subsurface magnitude: (L . t_sss) itself
    np.testing.assert_allclose(got["b"] - 0.2 * lt, ls, rtol=1e-4, atol=1e-5)


@pytest.fixture(scope="module")
def exported(tiny_run: Path) -> dict[str, Any]:
    from prt_torch.export import export_run

    return export_run(tiny_run, brdfs=("lambert", "phong"))


def test_export_ships_transfer_graph_matching_torch(tiny_run: Path, exported: dict[str, Any]) -> None:
    """``prt export`` writes ``transfer.onnx`` (listed in ``export.json`` with its sha256, recomputed here with
    hashlib); onnxruntime's outputs equal the torch models' transfer and subsurface and numpy's ``L . t``; the
    compare method runs that file (no copy in the compare directory)."""
    import hashlib

    import onnxruntime as ort
    import torch

    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import heldout_frames
    from prt_torch.models import load_model_file

    run = RunDir(tiny_run)
    entry = exported["transfer"]
    assert entry["arrays"] == ["transfer", "subsurface"] and entry["kind"] == "mlp" and entry["n_light"] == 9
    assert entry["parity"]["rel_error"] < 1e-4 and entry["subsurface"]["eta"] == 1.3
    path = run.transfer_graph_path
    assert exported["file_sha256"][run.relative(path)] == hashlib.sha256(path.read_bytes()).hexdigest()
    ctx = _compare_run(tiny_run)
    fs = heldout_frames(ctx, 4)
    light = np.random.default_rng(4).normal(size=(9, 3)).astype(np.float32)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    t, r, s, rs = sess.run(["transfer", "radiance", "subsurface", "subsurface_radiance"],
                           {"pose": fs.features.astype(np.float32), "light": light})
    with torch.no_grad():
        x = torch.from_numpy(fs.features.astype(np.float32))
        t_ref = load_model_file(run.transfer_model_path("mlp", "transfer"))(x).numpy().astype(np.float64)
        s_ref = load_model_file(run.transfer_model_path("mlp", "subsurface"))(x).numpy().astype(np.float64)
    for got, want in ((t, t_ref), (s, s_ref), (r, t_ref @ light), (rs, s_ref @ light)):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
    m = METHODS["learned_transfer"]()
    compare_copy = run.compare_graph_path("transfer_mlp")
    compare_copy.unlink(missing_ok=True)
    m.prepare(ctx, fs)
    assert m.graph.path == path and "exported by prt export" in m.runtime and not compare_copy.exists()


def test_player_transfer_radiance_is_numpy_dot_of_torch_transfer(tiny_run: Path, exported: dict[str, Any]) -> None:
    """``TransferPlayer``'s radiance of a clip frame = ``tint * (L . t) + tint / mean(tint) * (L . t_sss)`` with
    ``t``, ``t_sss`` the torch models' output for the frame's pose features and ``L`` the player's lighting SH (its
    first 9 coefficients), after a light rotation too (``rotate_lighting`` of the unrotated SH)."""
    import torch

    from prt_torch.light.rotation import rotate_lighting
    from prt_torch.models import load_model_file
    from prt_torch.transfer.player import TransferPlayer

    run = RunDir(tiny_run)
    p = TransferPlayer(tiny_run, threads=1, brdf="lambert")
    try:
        assert p.arrays == ["transfer", "subsurface"]
        loc = p.clip_locals("wave")[3:4]
        for angle in (0.0, 0.7):
            p.rotate_light(angle - p.light_angle)
            state, rad = p.compute(loc)
            c, s_ = np.cos(angle), np.sin(angle)
            R = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
            light = np.asarray(rotate_lighting(np.asarray(p.lighting.sh, np.float64), R))[:9]
            with torch.no_grad():
                x = torch.from_numpy(np.asarray(state.features, np.float32))
                t = load_model_file(run.transfer_model_path("mlp", "transfer"))(x).numpy().astype(np.float64)
                sss = load_model_file(run.transfer_model_path("mlp", "subsurface"))(x).numpy().astype(np.float64)
            want = _numpy_colour(t @ light, sss @ light, p.rpo.tint)
            assert rad.shape == (1, run.character().num_vertices, 3)
            np.testing.assert_allclose(rad, want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
    finally:
        p.close()


def test_play_transfer_command_without_torch(tiny_run: Path, exported: dict[str, Any], tmp_path: Path) -> None:
    """``prt play --renderer transfer`` writes frames and timings in a process that never imports torch."""
    from tests.torchfree import run_cli_without_torch

    png, timings = tmp_path / "png", tmp_path / "t.json"
    run_cli_without_torch(["play", str(tiny_run), "--clip", "wave", "--renderer", "transfer", "--max-frames", "2",
                           "--size", "96x128", "--png", str(png), "--timings", str(timings), "--threads", "1"])
    frames = sorted(png.glob("frame_*.png"))
    assert len(frames) == 2
    t = json.loads(timings.read_text())
    assert t["graph"] == "transfer" and t["summary"]["frames"] == 2 and t["summary"]["compute_fps"] > 0


def test_transfer_bad_input_is_one_line(tiny_run: Path, exported: dict[str, Any]) -> None:
    from prt_torch.transfer.player import TransferPlayer
    from prt_torch.transfer.shading import subsurface_tint, transfer_shading

    cases = [
        (lambda: transfer_shading(np.zeros((2, 3)), {"a": np.ones(3)}), "radiance must be"),
        (lambda: transfer_shading(np.zeros((1, 2, 3)), {"a": np.ones(3)}, np.zeros((1, 3, 3))), "subsurface"),
        (lambda: subsurface_tint(np.zeros(3)), "albedo"),
        (lambda: subsurface_tint([1.0, np.nan, 1.0]), "albedo"),
    ]
    for fn, msg in cases:
        with pytest.raises(PrtError, match=msg) as e:
            fn()
        assert "\n" not in str(e.value)
    p = TransferPlayer(tiny_run, threads=1)
    try:
        with pytest.raises(PrtError, match="pose features") as e:
            p.transfer_radiance(np.zeros((1, 3), np.float32))
        assert "\n" not in str(e.value)
    finally:
        p.close()
    run = RunDir(tiny_run)  # an export without the transfer graph: refused with one line naming the fix
    text = run.export_json.read_text()
    try:
        meta = json.loads(text)
        meta.pop("transfer")
        run.export_json.write_text(json.dumps(meta))
        with pytest.raises(PrtError, match="train.transfer") as e:
            TransferPlayer(tiny_run, threads=1)
        assert "\n" not in str(e.value)
    finally:
        run.export_json.write_text(text)
    record = run.transfer_json.read_bytes()  # retrained since the export (another transfer.json): stale, refused
    try:
        run.transfer_json.write_bytes(record + b"\n")
        with pytest.raises(PrtError, match="no current learned transfer graph") as e:
            TransferPlayer(tiny_run, threads=1)
        assert "\n" not in str(e.value)
    finally:
        run.transfer_json.write_bytes(record)
