"""Local visibility models (prt_torch.local.models, prt_torch.local.fit, prt_torch.local.soa).

Independent references: brute-force nearest neighbours (all distances, numpy argmin) for the neighbour pattern;
a per-(vertex, sample) loop of ``F_i @ (p_n - p_i)`` for the offsets; exact invariance under a rigid motion of the
subject (the FrameOperator's frames rotate with it); ordinary least squares with an explicit one-hot per-vertex
intercept (numpy lstsq) for the closed-form linear fit; the MLP's error going below half the best linear model's on
a target that is nonlinear in the offsets (and bit-identical refits for a seed); onnxruntime vs torch for the
shipped head.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from prt_torch.deform.clusters import spatial_clusters
from prt_torch.deform.frames import FrameOperator
from prt_torch.errors import PrtError
from prt_torch.fit.config import LocalConfig
from prt_torch.local.fit import fit_local, fit_local_linear
from prt_torch.local.models import (
    LocalVisibility,
    load_local,
    local_offsets,
    neighbour_pattern,
    sample_offsets,
    save_local,
)
from prt_torch.local.soa import LocalOffsetsSoA, offsets_inputs
from tests.deform.sheets import sheet
from tests.tolerance import assert_bitwise

RADII = [0.08, 0.2]
ANGLES = 6


@pytest.fixture(scope="module")
def waving_sheet() -> dict[str, np.ndarray]:
    """A 15 x 12 sheet under travelling waves (12 frames), its FrameOperator frames and rest frames."""
    rest, faces = sheet(15, 12, 1.0, 0.8)
    op = FrameOperator.from_rest(rest, faces, spatial_clusters(rest, 4, 0))
    t = np.arange(12)[:, None]
    x, y = rest[None, :, 0], rest[None, :, 1]
    pos = np.repeat(rest[None], 12, axis=0).copy()
    pos[..., 2] = 0.12 * np.sin(6.0 * x - 0.7 * t) * (0.3 + x) + 0.04 * np.cos(5.0 * y + 0.4 * t)
    frames = np.asarray(op.frames(pos), np.float32)
    return {"rest": rest.astype(np.float32), "faces": faces, "pos": pos.astype(np.float32), "frames": frames,
            "rest_frames": op.rest_frames.astype(np.float32)}


def test_neighbour_pattern_is_the_nearest_rest_vertex(waving_sheet: dict[str, np.ndarray]) -> None:
    rest, rf = waving_sheet["rest"], waving_sheet["rest_frames"]
    nb = neighbour_pattern(rest, rf, RADII, ANGLES)
    assert nb.shape == (len(rest), len(RADII) * ANGLES)
    a = 2 * np.pi * np.arange(ANGLES) / ANGLES
    for s, (r, ang) in enumerate((r, ang) for r in RADII for ang in a):  # radius-major
        target = rest + r * (np.cos(ang) * rf[:, 0] + np.sin(ang) * rf[:, 1])
        d = np.linalg.norm(target[:, None] - rest[None], axis=-1)
        np.testing.assert_allclose(d[np.arange(len(rest)), nb[:, s]], d.min(axis=1), atol=1e-6)


def test_offsets_match_a_per_vertex_loop_and_the_numpy_twin(waving_sheet: dict[str, np.ndarray]) -> None:
    pos, fr = waving_sheet["pos"][:3], waving_sheet["frames"][:3]
    nb = neighbour_pattern(waving_sheet["rest"], waving_sheet["rest_frames"], RADII, ANGLES)
    S = nb.shape[1]
    x = local_offsets(torch.from_numpy(pos), torch.from_numpy(fr), torch.from_numpy(nb)).numpy()
    ref = np.empty_like(x)
    for b in range(pos.shape[0]):
        for i in range(pos.shape[1]):
            for s in range(S):
                loc = fr[b, i].astype(np.float64) @ (pos[b, nb[i, s]] - pos[b, i]).astype(np.float64)
                ref[b, i, [s, S + s, 2 * S + s]] = loc  # component-major
    np.testing.assert_allclose(x, ref, atol=1e-6)
    for engine in LocalOffsetsSoA.ENGINES:  # the compiled pass and the numpy rule
        twin = LocalOffsetsSoA(nb, engine=engine)(*offsets_inputs(pos, fr))
        np.testing.assert_allclose(twin, x.transpose(0, 2, 1), atol=1e-6, err_msg=engine)
    fi = torch.tensor([0, 2, 1, 2])
    vi = torch.tensor([5, 0, 100, 179])
    np.testing.assert_allclose(sample_offsets(torch.from_numpy(pos), torch.from_numpy(fr), torch.from_numpy(nb), fi,
                                              vi).numpy(), x[fi.numpy(), vi.numpy()], atol=1e-7)


def test_model_is_invariant_under_rigid_motion(waving_sheet: dict[str, np.ndarray]) -> None:
    """Rotate and translate the whole subject: the FrameOperator's frames rotate with it (rows F R^T), the offsets
    in each vertex's frame and so the visibility stay (up to rounding)."""
    w = waving_sheet
    op = FrameOperator.from_rest(w["rest"].astype(np.float64), w["faces"],
                                 spatial_clusters(w["rest"].astype(np.float64), 4, 0))
    rot = Rotation.from_euler("xyz", [0.4, -1.1, 2.3]).as_matrix()
    moved = (w["pos"][:4].astype(np.float64) @ rot.T + np.array([3.0, -1.0, 0.5])).astype(np.float32)
    fr_moved = np.asarray(op.frames(moved), np.float32)
    np.testing.assert_allclose(fr_moved, w["frames"][:4] @ rot.T.astype(np.float32), atol=2e-5)
    rng = np.random.default_rng(0)
    nb = neighbour_pattern(w["rest"], w["rest_frames"], RADII, ANGLES)
    V, S = nb.shape
    model = LocalVisibility("mlp", nb, [rng.normal(size=(3 * S, 8)), rng.normal(size=(8, 9))],
                            [rng.normal(size=(V, 8))], rng.normal(size=(V, 9)))
    a = model.predict(w["pos"][:4], w["frames"][:4])
    b = model.predict(moved, fr_moved)
    np.testing.assert_allclose(b, a, atol=2e-4 * np.abs(a).max())


def test_closed_form_linear_is_least_squares_with_vertex_intercepts(waving_sheet: dict[str, np.ndarray]) -> None:
    w = waving_sheet
    nb = neighbour_pattern(w["rest"], w["rest_frames"], [0.1], 4)
    V, S = nb.shape
    rng = np.random.default_rng(1)
    y = rng.normal(size=(12, V, 4)).astype(np.float32)
    model = fit_local_linear(w["pos"], w["frames"], y, nb, LocalConfig(alpha=0.0, radii=[0.1], angles=4))
    x = local_offsets(torch.from_numpy(w["pos"]), torch.from_numpy(w["frames"]), torch.from_numpy(nb)).double()
    design = np.concatenate([x.reshape(-1, 3 * S).numpy(), np.tile(np.eye(V), (12, 1))], axis=1)
    coef, *_ = np.linalg.lstsq(design, y.reshape(-1, 4).astype(np.float64), rcond=None)
    ref = (design @ coef).reshape(12, V, 4)
    # the intercepts are rounded to float16 values at the end of the fit: the difference is that rounding, the
    # same in every frame and at most half a float16 step (2^-11 relative) of the intercept
    diff = model.predict(w["pos"], w["frames"]) - ref
    np.testing.assert_allclose(diff, np.broadcast_to(diff[:1], diff.shape), atol=2e-5)
    m = model.head.mean.numpy()
    assert (np.abs(diff[0]) <= 2.0**-11 * np.abs(m) + 2e-5).all()


def test_mlp_learns_what_a_linear_model_cannot(waving_sheet: dict[str, np.ndarray]) -> None:
    """A target nonlinear in the local shape (|curvature|-like: the absolute normal offset of the near ring): the
    network's training error ends well below the best linear model's."""
    w = waving_sheet
    cfg = LocalConfig(radii=[0.08], angles=4, hidden=[16], steps=1500, batch=256, lr=1e-2)
    nb = neighbour_pattern(w["rest"], w["rest_frames"], cfg.radii, cfg.angles)
    x = local_offsets(torch.from_numpy(w["pos"]), torch.from_numpy(w["frames"]), torch.from_numpy(nb)).numpy()
    n_off = x[..., 2 * nb.shape[1]:]  # the normal components of the offsets
    y = np.stack([np.abs(n_off).sum(-1), np.abs(n_off).sum(-1) ** 2], axis=-1).astype(np.float32) * 10

    def err(m: LocalVisibility) -> float:
        return float(np.sqrt(((m.predict(w["pos"], w["frames"]) - y) ** 2).mean() / y.var()))

    lin, _ = fit_local("linear", w["pos"], w["frames"], y, w["rest"], w["rest_frames"], cfg, 0)
    mlp, _ = fit_local("mlp", w["pos"], w["frames"], y, w["rest"], w["rest_frames"], cfg, 0)
    from prt_torch.local.graph import table_lowering

    for m in (lin, mlp):  # fits leave the per-vertex tables on the float16 grid: the export stores them exactly
        assert table_lowering(m.head)["fp16_weights"] is not None
    assert err(mlp) < 0.5 * err(lin), (err(mlp), err(lin))
    mlp2, _ = fit_local("mlp", w["pos"], w["frames"], y, w["rest"], w["rest_frames"], cfg, 0)
    for k, v in mlp.arrays().items():  # seeded: the same model again
        torch.testing.assert_close(mlp2.arrays()[k], v, rtol=0, atol=0)


def test_save_load_round_trip_and_bad_files(tmp_path: Path, waving_sheet: dict[str, np.ndarray]) -> None:
    w = waving_sheet
    nb = neighbour_pattern(w["rest"], w["rest_frames"], RADII, ANGLES)
    rng = np.random.default_rng(2)
    V, S = nb.shape
    m = LocalVisibility("mlp", nb, [rng.normal(size=(3 * S, 5)), rng.normal(size=(5, 5)), rng.normal(size=(5, 4))],
                        [rng.normal(size=(V, 5)), rng.normal(size=5)], rng.normal(size=(V, 4)), {"radii": RADII})
    save_local(m, tmp_path / "m.pt")
    back = load_local(tmp_path / "m.pt")
    assert_bitwise(back.predict(w["pos"][:2], w["frames"][:2]), m.predict(w["pos"][:2],
                                                                                         w["frames"][:2]),
                   why='the same operations on round-tripped tables')
    assert back.meta == {"radii": RADII}
    (tmp_path / "bad.pt").write_bytes(b"not a model")
    for path, msg in ((tmp_path / "bad.pt", "not a prt_torch local model file"),
                      (tmp_path / "none.pt", "local model file not found")):
        with pytest.raises(PrtError, match=msg) as e:
            load_local(path)
        assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match=r"needs positions \(F, 180, 3\)"):
        m.predict(w["pos"][:, :10], w["frames"][:, :10])
    with pytest.raises(PrtError, match="first bias must be"):
        LocalVisibility("mlp", nb, [np.zeros((3 * S, 5)), np.zeros((5, 4))], [np.zeros((V + 1, 5))],
                        np.zeros((V, 4)))
    with pytest.raises(PrtError, match="neighbour indices must be integers"):
        LocalOffsetsSoA(np.array([[0, 5]]))
    with pytest.raises(PrtError, match="unknown local offsets engine"):
        LocalOffsetsSoA(nb, engine="cuda")


def test_head_runs_the_same_in_onnxruntime(tmp_path: Path, waving_sheet: dict[str, np.ndarray]) -> None:
    from prt_torch.export.onnx_file import export_onnx
    from prt_torch.runtime.session import OrtGraph

    w = waving_sheet
    nb = neighbour_pattern(w["rest"], w["rest_frames"], RADII, ANGLES)
    rng = np.random.default_rng(3)
    V, S = nb.shape
    for m in (LocalVisibility("linear", nb, [rng.normal(size=(3 * S, 9))], [], rng.normal(size=(V, 9))),
              LocalVisibility("mlp", nb, [rng.normal(size=(3 * S, 6)), rng.normal(size=(6, 9))],
                              [rng.normal(size=(V, 6))], rng.normal(size=(V, 9)))):
        x = LocalOffsetsSoA(nb)(*offsets_inputs(w["pos"][:3], w["frames"][:3]))
        path = export_onnx(m.head, [torch.from_numpy(x)], tmp_path / f"{m.kind}.onnx", ("offsets",),
                           ("visibility",), {"offsets": {0: "B"}, "visibility": {0: "B"}})
        out = OrtGraph(path, threads=1).run({"offsets": x})["visibility"]
        np.testing.assert_allclose(out, m.predict(w["pos"][:3], w["frames"][:3]), rtol=1e-5, atol=1e-5)


def test_fp16_tables_are_stored_exactly(tmp_path: Path, waving_sheet: dict[str, np.ndarray]) -> None:
    """Tables on the float16 grid (as fits leave them) are stored in float16: fewer bytes, onnxruntime still equal
    to torch; tables off the grid stay float32."""
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.local.fit import to_fp16_grid
    from prt_torch.local.graph import table_lowering
    from prt_torch.runtime.session import OrtGraph

    w = waving_sheet
    nb = neighbour_pattern(w["rest"], w["rest_frames"], RADII, ANGLES)
    rng = np.random.default_rng(4)
    V, S = nb.shape
    b0, mean = rng.normal(size=(V, 6)).astype(np.float32), rng.normal(size=(V, 9)).astype(np.float32)
    x = LocalOffsetsSoA(nb)(*offsets_inputs(w["pos"][:2], w["frames"][:2]))
    sizes = {}
    for grid in (False, True):
        t0, m0 = (to_fp16_grid(torch.from_numpy(b0)), to_fp16_grid(torch.from_numpy(mean))) if grid else (b0, mean)
        m = LocalVisibility("mlp", nb, [rng.normal(size=(3 * S, 6)), rng.normal(size=(6, 9))], [t0], m0)
        low = table_lowering(m.head)
        assert (low["fp16_weights"] is not None) == grid
        path = export_onnx(m.head, [torch.from_numpy(x)], tmp_path / f"{grid}.onnx", ("offsets",), ("visibility",),
                           {"offsets": {0: "B"}, "visibility": {0: "B"}}, **low)
        out = OrtGraph(path, threads=1).run({"offsets": x})["visibility"]
        np.testing.assert_allclose(out, m.head(torch.from_numpy(x)).detach().numpy(), rtol=1e-5, atol=1e-5)
        sizes[grid] = initializer_bytes(path)
    assert sizes[True] < 0.6 * sizes[False], sizes


def test_train_local_on_a_skinned_dataset_is_one_line_error(synthetic_dataset: Path, tmp_path: Path) -> None:
    """``train.local`` needs a deformable dataset; bad local settings are refused by the config."""
    from pydantic import ValidationError

    from prt_torch.fit.config import TrainConfig
    from prt_torch.fit.train import train_dataset

    cfg = TrainConfig(kinds=["linear"], folds=2, alphas=[1.0], local=LocalConfig(steps=1))
    with pytest.raises(PrtError, match="train.local needs a deformable") as e:
        train_dataset(synthetic_dataset, tmp_path / "run", cfg)
    assert "\n" not in str(e.value)
    assert not list((tmp_path / "run").rglob("*.pt"))  # refused before anything was fitted
    for bad in ({"radii": [-0.1]}, {"hidden": [0]}, {"kinds": ["linear"], "default": "mlp"}, {"kinds": ["cubic"]},
                {"lr": float("nan")}):
        with pytest.raises(ValidationError):
            LocalConfig(**bad)
