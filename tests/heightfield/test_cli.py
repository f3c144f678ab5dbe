"""``prt heightfield`` / ``prt bench heightfield``: the report's contents and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.cli import main


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A tiny report: JSON keys, HF beats unshadowed in SH error and image PSNR, the table and image exist."""
    code, out, err = _run(capsys, "bench", "heightfield", "--sizes", "24", "--frames", "1", "--kinds", "terrain",
                          "--rays", "128", "--repeat", "1", "--wedges", "8", "--out", str(tmp_path), "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res == json.loads((tmp_path / "heightfield.json").read_text())
    s = res["sizes"]["24"]
    assert s["vertices"] == 24 * 24 and s["triangles"] == 2 * 23 * 23 and s["stride"] == 1
    m = s["summary"]
    assert m["vis_rel_err"] < 0.5 * m["vis_rel_err_unshadowed"]
    assert m["psnr_image_diffuse"] > m["psnr_image_diffuse_unshadowed"]
    assert m["psnr_image_glossy"] > m["psnr_image_glossy_unshadowed"]
    assert m["ms_per_frame"] > 0 and m["speedup"] == pytest.approx(m["embree_ms_per_frame"] / m["ms_per_frame"])
    assert s["bytes"]["table"] > 0
    assert "| 24 |" in (tmp_path / "heightfield.md").read_text()
    import cv2

    img = cv2.imread(str(tmp_path / "terrain_24.png"))
    assert img is not None and img.shape[0] == 4 * 480 and img.shape[1] == 3 * 640
    assert np.std(img[:480, :640]) > 5  # the truth image shows something


@pytest.mark.parametrize("argv,words", [
    (["--sizes", "3"], "grid size"),
    (["--sizes", "16,x"], "--sizes"),
    (["--wedges", "0"], "wedges"),
    (["--kinds", "lava"], "--kinds"),
    (["--frames", "0"], "--frames"),
])
def test_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: str) -> None:
    code, out, err = _run(capsys, "heightfield", *argv, "--out", str(tmp_path / "r"))
    assert code == 2
    line = err.strip()
    assert line.startswith("error:") and "\n" not in line and words in line, line
