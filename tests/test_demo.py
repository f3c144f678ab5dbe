"""``prt demo`` end to end on a tiny config: MP4, side-by-side PNG, metrics; re-running reuses the
finished steps (bake, fit, export untouched)."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v2 as iio
import numpy as np
import pytest

from tests.export.pipeline import build_tiny_run


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())


def test_demo_outputs(tiny_run: Path) -> None:
    video = tiny_run / "heldout.mp4"
    assert sum(1 for _ in iio.get_reader(video)) == 4
    png = iio.imread(tiny_run / "comparison.png")
    assert png.shape == (2 * 240, 4 * 160, 3)
    shaded, blocked = np.split(png.astype(float), 2, axis=0)
    panels = np.split(shaded, 4, axis=1)
    assert all(p.std() > 5 for p in panels)  # four rendered characters: reference, truth, model, unshadowed
    _, truth_blocked, model_blocked, error = np.split(blocked, 4, axis=1)
    # the light-blocked maps show shadowing (bright pixels), and the model's error map is darker than the truth map
    assert truth_blocked.mean() > 1.0 and model_blocked.mean() > 1.0
    assert error.mean() < truth_blocked.mean()
    m = json.loads((tiny_run / "demo_metrics.json").read_text())
    h = m["heldout"]
    # the learned model is closer to the ray-traced truth than ignoring shadows
    assert h["vis_rel_err_model"] < h["vis_rel_err_unshadowed"]
    assert h["radiance_rel_rmse_model"] < h["radiance_rel_rmse_unshadowed"]
    # the reference column: the rendering integral by Monte-Carlo, which the ray-traced truth (SH visibility, exact
    # peak visibility) approaches on the front-facing vertices
    ref = h["reference"]
    assert ref["front_facing_vertices"] > 0 and ref["radiance_rel_rmse_truth"] < 0.25
    assert h["peaks"] and len(h["peaks"][0]["direction"]) == 3  # the sky's sun, a peak light
    assert all(v <= 1e-4 for v in m["onnx_parity_rel_error"].values())
    assert m["play"]["frames"] == 4 and m["sh_order"] == 4
    assert (tiny_run / "heldout.timings.json").is_file()


def test_demo_rerun_reuses_finished_steps(tiny_run: Path) -> None:
    from prt_torch.cli import main

    files = ["model.pt", "fused.onnx", "visibility.onnx", "export.json"]
    before = {f: (tiny_run / f).stat().st_mtime_ns for f in files}
    cfg = tiny_run.parent / "tiny.yaml"
    assert main(["demo", "--config", str(cfg), "--frames", "2", "--size", "240x160"]) == 0
    assert {f: (tiny_run / f).stat().st_mtime_ns for f in files} == before
    assert sum(1 for _ in iio.get_reader(tiny_run / "heldout.mp4")) == 2


def test_demo_bad_config(tmp_path: Path) -> None:
    from prt_torch.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ncharacter: {source: builtin}\nbake: {n_rayz: 3}\n")
    assert main(["demo", "--config", str(bad)]) == 2
