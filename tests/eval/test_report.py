"""``prt eval`` end to end on ``small_run``: JSON schema, report files, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.cli import main
from prt_torch.rundir import RunDir

KINDS = ("linear", "quadratic", "mlp")


def test_prt_eval_json_and_report(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(small_run), "--frames", "8", "--image-frames", "2", "--lights", "sky", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == {"train": 8, "heldout": 8} and out["image_frames"] == {"train": 2, "heldout": 2}
    assert out["brdfs"] == ["lambert", "phong"] and out["paths"] == ["exact", "lobes"]
    assert list(out["lights"]) == ["sky"]
    for kind in (*KINDS, "unshadowed"):
        for split in ("train", "heldout"):
            m = out["models"][kind][split]
            assert m["frames"] == 8
            for key in ("vis_rel_err", "psnr_diffuse", "psnr_glossy", "jitter", "transfer_rel_err", "rmse_glossy"):
                assert np.isfinite(m[key]), (kind, split, key)
            for brdf in ("lambert", "phong"):
                for path in ("exact", "lobes"):
                    s = m["shading"]["sky"][brdf][path]
                    assert set(s) == {"radiance_rel_rmse", "psnr_vertex", "psnr_image"}
                    assert all(np.isfinite(v) for v in s.values()), (kind, split, brdf, path)
            # the flat keys are the player's light, lobes path
            assert m["psnr_diffuse"] == m["shading"]["sky"]["lambert"]["lobes"]["psnr_image"]
            assert m["psnr_glossy"] == m["shading"]["sky"]["phong"]["lobes"]["psnr_image"]
    for kind in KINDS:
        s = out["storage"][kind]
        assert s["bytes"] > 0 and s["ptd"] > 0 and s["psm"] > 0
    # the models shadow: every kind beats no shadowing on the held-out visibility, radiance and image
    ns = out["models"]["unshadowed"]["heldout"]
    for kind in KINDS:
        m = out["models"][kind]["heldout"]
        assert m["vis_rel_err"] < ns["vis_rel_err"]
        assert m["psnr_diffuse"] > ns["psnr_diffuse"]
        assert m["rmse_diffuse"] < ns["rmse_diffuse"]
    # the lobe fit of the sky costs something, but little
    lf = out["lobe_fit"]["heldout"]["sky"]["lambert"]
    assert 0 < lf["radiance_rel_rmse"] < 0.2 and lf["psnr_image"] > 25
    rep = RunDir(small_run).report_dir
    index = (rep / "index.md").read_text()
    for png in ("spectra.png", "error_vs_variance.png", "error_vs_alpha.png", "per_frame_error.png", "frame.png"):
        assert (rep / png).stat().st_size > 1000, png
        assert png in index
    assert "8 frames" in index and "lobes" in index
    assert (rep / "index.html").is_file() and json.loads(RunDir(small_run).report_json.read_text())["models"]


def test_prt_eval_table_says_frames(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(small_run), "--frames", "4", "--image-frames", "0", "--lights", "sky",
                 "--no-report"]) == 0
    err = capsys.readouterr().err
    assert "heldout: 4 frames" in err and "exact" in err and "lobes" in err
    r = json.loads(RunDir(small_run).report_json.read_text())
    assert r["models"]["mlp"]["heldout"]["psnr_diffuse"] is None  # no frame rendered
    assert r["models"]["mlp"]["heldout"]["shading"]["sky"]["phong"]["exact"]["psnr_vertex"] > 0


def test_prt_eval_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path / "missing")]) == 2
    assert "run directory not found" in capsys.readouterr().err
    assert main(["eval", str(tmp_path)]) == 2
    assert "model metadata not found" in capsys.readouterr().err
