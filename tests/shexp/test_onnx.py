"""The SHEXP ONNX graph: onnxruntime vs torch, and vs the functional API."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")


def test_onnx_matches_torch(tmp_path: Path) -> None:
    below = "zero"
    from prt_torch.export.onnx_file import read_metadata
    from prt_torch.runtime.session import OrtGraph
    from prt_torch.shexp import shexp_visibility
    from prt_torch.shexp.graph import SHEXP_INPUTS, example_inputs, export_shexp, shexp_parity

    path = export_shexp(tmp_path / "shexp.onnx", 3, below_horizon=below)
    meta = read_metadata(path)
    assert meta["kind"] == "shexp" and meta["order"] == "3"
    # parity on other sizes than the trace (B, V, S dynamic), receivers inside some spheres included
    par = shexp_parity(path, 3, below_horizon=below)
    assert par.rel_error < 1e-4
    ex = example_inputs(n_vertices=40, n_spheres=9, batch=3, seed=5)
    ex["points"][0, :3] = ex["centers"][0, :3]  # receivers at sphere centres: those spheres are ignored
    got = OrtGraph(path).run({k: ex[k] for k in SHEXP_INPUTS})["visibility"]
    want = shexp_visibility(ex["points"], ex["centers"], ex["radii"], 3, frames=ex["frames"],
                            below_horizon=below).numpy()
    assert got.shape == (3, 40, 9)
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()
