"""``prt light``: JSON schema and values, tables, one-line errors with exit status 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from prt_torch.cli import main
from prt_torch.light.envmap import latlong_directions
from prt_torch.light.readers import write_pfm
from prt_torch.sh.basis import sh_basis


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_json_band_limited_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    sh = rng.normal(size=(9, 3))
    sh[0] += 5
    write_pfm(tmp_path / "m.pfm", (sh_basis(latlong_directions(64, 128), 3) @ sh).astype(np.float32))
    code, out, err = _run(capsys, "light", str(tmp_path / "m.pfm"), "--order", "3", "--lobes", "2", "--json")
    assert code == 0, err
    obj = json.loads(out)
    assert obj["order"] == 3 and obj["layout"] == "latlong" and (obj["width"], obj["height"]) == (128, 64)
    coeffs = np.array(obj["coefficients"])
    assert coeffs.shape == (9, 3)
    np.testing.assert_allclose(coeffs, sh, atol=0.01 * np.abs(sh).max())
    assert len(obj["lobes"]) == 2 and 0 <= obj["lobe_rel_error"] < 1
    assert np.array(obj["lobes"][0]["coeffs"]).shape == (3, 3)
    assert abs(np.linalg.norm(obj["lobes"][0]["direction"]) - 1) < 1e-9


def test_json_uffizi_and_table(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = str(shared_data / "envmaps" / "uffizi.hdr")
    code, out, _ = _run(capsys, "light", path, "--order", "2", "--json")
    assert code == 0
    obj = json.loads(out)
    assert "lobes" not in obj
    np.testing.assert_allclose(obj["coefficients"][0], [3.172, 3.077, 3.501], atol=6e-4)
    code, out, _ = _run(capsys, "light", path, "--order", "2", "--lobes", "3")
    assert code == 0 and "SH order 2" in out and "3 ZH lobes" in out


def test_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_pfm(tmp_path / "ok.pfm", np.ones((8, 16, 3), np.float32))
    nan = np.ones((8, 16, 3), np.float32)
    nan[2, 3] = np.inf
    write_pfm(tmp_path / "nan.pfm", nan)
    write_pfm(tmp_path / "odd.pfm", np.ones((8, 13, 3), np.float32))
    (tmp_path / "x.png").write_bytes(b"png")
    cases = [
        ((str(tmp_path / "missing.hdr"),), "not found"),
        ((str(tmp_path / "x.png"),), "unknown HDR image format"),
        ((str(tmp_path / "ok.pfm"), "--order", "0"), "unsupported SH order"),
        ((str(tmp_path / "ok.pfm"), "--order", "17"), "unsupported SH order"),
        ((str(tmp_path / "ok.pfm"), "--lobes", "0"), "--lobes"),
        ((str(tmp_path / "nan.pfm"),), "NaN or Inf"),
        ((str(tmp_path / "odd.pfm"),), "cannot infer"),
    ]
    for argv, msg in cases:
        code, out, err = _run(capsys, "light", *argv)
        assert code == 2, (argv, err)
        assert err.startswith("error: ") and msg in err and err.count("\n") == 1, err
        assert "Traceback" not in err and out == ""
    code, out, _ = _run(capsys, "light", str(tmp_path / "ok.pfm"), "--order", "1", "--json")
    assert json.loads(out)["coefficients"][0][0] == pytest.approx(math.sqrt(4 * math.pi))
