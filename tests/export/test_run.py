"""export_run on a real (tiny) baked + trained run: checked ONNX files, metadata, parity with torch on
held-out poses, fused == split, up-to-date reuse, CLI entry points and errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
import zarr

from prt_torch.errors import PrtError
from prt_torch.export.onnx_file import opset_of, read_metadata
from prt_torch.export.run import export_run
from prt_torch.models.visibility import load_model
from prt_torch.rig.character import Character
from prt_torch.runtime.session import OrtGraph


def _heldout(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    g = zarr.open_group(str(run / "dataset.zarr"), mode="r")
    names = list(g.attrs["clip_names"])
    ids = [names.index(c) for c in g.attrs["splits"]["heldout"]]
    rows = np.flatnonzero(np.isin(g["clip_id"][:], ids))
    assert rows.size >= 3
    sel = (rows,)
    return (np.asarray(g["pose"].get_orthogonal_selection((rows, slice(None)))),
            np.asarray(g["frames"].get_orthogonal_selection(sel)),
            np.asarray(g["positions"].get_orthogonal_selection(sel)))


def test_files_checked_with_metadata(tiny_run: Path) -> None:
    meta = json.loads((tiny_run / "export.json").read_text())
    ch = Character.load(tiny_run / "character.npz")
    for name in ("visibility", "shading", "fused"):
        path = tiny_run / meta["files"][name]
        onnx.checker.check_model(onnx.load(str(path)), full_check=True)
        assert opset_of(path) >= 17
        md = read_metadata(path)
        assert md["prt.sh_order"] == "4" and md["prt.n_coeffs"] == "16"
        assert md["prt.n_vertices"] == str(ch.num_vertices)
        assert md["prt.character_hash"] == ch.content_hash()
        assert "Condon-Shortley" in md["prt.conventions"] and md["prt.graph"] == name
        assert meta["parity"][name]["rel_error"] <= 1e-4
    assert set(meta["brdfs"]) >= {"lambert", "phong"}


def test_visibility_parity_on_all_heldout_poses(tiny_run: Path) -> None:
    """Independently of export_run's own check: ORT vs the float32 torch model on every held-out pose, within the
    stated error of the run's weight precision (tests/export/test_precision.py: INT8_REL / FP16_REL)."""
    from tests.export.test_precision import STATED_REL

    pose, _, _ = _heldout(tiny_run)
    model = load_model(tiny_run)
    with torch.no_grad():
        want = model(torch.from_numpy(pose)).numpy()
    got = OrtGraph(tiny_run / "visibility.onnx").run({"pose": pose})["visibility"]
    prec = json.loads((tiny_run / "export.json").read_text())["precision"]
    assert got.shape == want.shape == (len(pose), model.n_vertices, 16)
    assert np.abs(got - want).max() <= STATED_REL[prec] * np.abs(want).max()


def test_fused_equals_visibility_then_shading(tiny_run: Path) -> None:
    from prt_torch.export.run import _example_lobes, _frames_vertex_last, _view_dirs, default_eye, pad_rpo
    from prt_torch.player.bundle import load_rpo_tensors

    pose, frames, pos = _heldout(tiny_run)
    pose, frames, pos = pose[:4], frames[:4], pos[:4]
    rpo = load_rpo_tensors(tiny_run / "rpo" / "phong.npz", 4, 8)
    dirs, coeffs = _example_lobes(4)
    common = {"frames": _frames_vertex_last(frames), "view_dirs": _view_dirs(pos, default_eye(pos)),
              "lobe_dirs": dirs, "lobe_coeffs": coeffs, "rpo_M": rpo.M, "rpo_w": rpo.w, "rpo_tint": rpo.tint}
    vis = OrtGraph(tiny_run / "visibility.onnx").run({"pose": pose})["visibility"]
    split = OrtGraph(tiny_run / "shading.onnx").run({"visibility": vis, **common})["radiance"]
    # the fused graph's vertex axes are in the cluster-sorted order of the frame data (format /3 contract)
    meta = json.loads((tiny_run / "export.json").read_text())
    assert meta["fused_vertex_order"] == "cluster"
    order = np.load(tiny_run / "frames.npz")["vertex_order"]
    assert np.array_equal(np.sort(order), np.arange(vis.shape[1]))
    sorted_in = {k: np.ascontiguousarray(common[k][:, :, order]) for k in ("frames", "view_dirs")}
    fused_sorted = OrtGraph(tiny_run / "fused.onnx").run({"pose": pose, **common, **sorted_in})["radiance"]
    fused = np.empty_like(fused_sorted)
    fused[:, order] = fused_sorted
    assert fused.shape == (4, vis.shape[1], 3)
    np.testing.assert_allclose(fused, split, rtol=1e-4, atol=1e-4 * np.abs(split).max())
    M, w = pad_rpo(rpo, 8)
    assert M.shape == (8, 16, 16) and w.shape == (8, 16)


def test_up_to_date_export_is_reused_and_cli(tiny_run: Path) -> None:
    from prt_torch.cli import main

    before = (tiny_run / "fused.onnx").stat().st_mtime_ns
    meta = export_run(tiny_run)
    assert (tiny_run / "fused.onnx").stat().st_mtime_ns == before
    assert meta["n_vertices"] == Character.load(tiny_run / "character.npz").num_vertices
    assert main(["export", str(tiny_run)]) == 0
    assert (tiny_run / "fused.onnx").stat().st_mtime_ns == before


def test_python_m_export_entry_point(tiny_run: Path) -> None:
    repo = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-m", "export", str(tiny_run)], cwd=repo, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    r = subprocess.run([sys.executable, "-m", "export", str(tiny_run / "nope")], cwd=repo, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 2 and "error: run directory not found" in r.stderr


def test_export_errors(tiny_run: Path, tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="run directory not found"):
        export_run(tmp_path / "missing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(PrtError, match="model"):
        export_run(empty)
    # a run whose character.npz is another character: refused before anything is written
    other = tmp_path / "other"
    shutil.copytree(tiny_run, other, ignore=shutil.ignore_patterns("*.onnx", "export.json", "*.mp4"))
    from prt_torch.rig.builtin import make_character

    make_character(density=0.05).save(other / "character.npz")
    with pytest.raises(PrtError, match="vertices|features"):
        export_run(other)
    assert not (other / "fused.onnx").exists()
