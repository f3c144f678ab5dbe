"""``prt eval`` end to end on ``small_run``: JSON keys, report files, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.cli import main


def test_prt_eval_json_and_report(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(small_run), "--frames", "8", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for kind in ("linear", "quadratic", "mlp"):
        for split in ("train", "heldout"):
            m = out["models"][kind][split]
            for key in ("vis_rel_err", "psnr_diffuse", "psnr_glossy", "jitter", "transfer_rel_err"):
                assert np.isfinite(m[key]), (kind, split, key)
        s = out["storage"][kind]
        assert s["bytes"] > 0 and s["ptd"] > 0 and s["psm"] > 0
    # the models shadow: every kind beats no shadowing on the held-out visibility and diffuse radiance
    ns = out["models"]["noshadow"]["heldout"]
    for kind in ("linear", "quadratic", "mlp"):
        assert out["models"][kind]["heldout"]["vis_rel_err"] < ns["vis_rel_err"]
        assert out["models"][kind]["heldout"]["psnr_diffuse"] > ns["psnr_diffuse"]
    rep = small_run / "report"
    index = (rep / "index.md").read_text()
    for png in ("spectra.png", "error_vs_variance.png", "error_vs_alpha.png", "per_frame_error.png", "frame.png"):
        assert (rep / png).stat().st_size > 1000, png
        assert png in index
    assert (rep / "index.html").is_file() and json.loads((rep / "results.json").read_text())["models"]


def test_prt_eval_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path / "missing")]) == 2
    assert "run directory not found" in capsys.readouterr().err
    assert main(["eval", str(tmp_path)]) == 2
    assert "model metadata not found" in capsys.readouterr().err
