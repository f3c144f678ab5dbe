"""``prt light``: JSON schema and values, tables, one-line errors with exit status 2."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
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
    sh[0] += 8  # a map of radiance > 0 everywhere (negative pixels would be clamped)
    img = (sh_basis(latlong_directions(64, 128), 3) @ sh).astype(np.float32)
    assert img.min() > 0
    write_pfm(tmp_path / "m.pfm", img)
    code, out, err = _run(capsys, "light", str(tmp_path / "m.pfm"), "--order", "3", "--lobes", "2", "--json")
    assert code == 0 and err == "", err
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


def test_negative_radiance_is_clamped_with_one_warning_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A constant map of radiance 1 with 5 negative pixels: one ``warning:`` line, and the SH of the clamped map
    (DC = sqrt(4 pi) times the mean radiance over the sphere, the clamped pixels counting as 0)."""
    from prt_torch.light.envmap import latlong_solid_angles

    img = np.ones((8, 16, 3), np.float32)
    bad = [(0, 0), (3, 5), (4, 5), (7, 15), (2, 9)]
    for r, c in bad:
        img[r, c] = -3.0
    write_pfm(tmp_path / "neg.pfm", img)
    code, out, err = _run(capsys, "light", str(tmp_path / "neg.pfm"), "--order", "1", "--json")
    assert code == 0, err
    assert err == "warning: neg.pfm: clamped negative radiance to 0 in 5 of 128 pixel(s) (lowest value -3)\n"
    omega = latlong_solid_angles(8, 16)
    lit = np.ones((8, 16))
    for r, c in bad:
        lit[r, c] = 0.0
    want = (omega * lit).sum() / math.sqrt(4 * math.pi)  # int L y_00 = int L / sqrt(4 pi)
    assert json.loads(out)["coefficients"][0] == pytest.approx([want] * 3, rel=1e-6)


# ------------------------------------------------------------------------------------------ --sg (seed 004)


def test_sg_json_on_real_maps(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    from prt_torch.light.envmap import load_envmap
    from prt_torch.sg.lobes import SGLobes

    path = shared_data / "envmaps" / "spiaggia_di_mondello_1k.hdr"
    code, out, err = _run(capsys, "light", str(path), "--order", "1", "--sg", "--sg-levels", "3", "--json",
                          "--sg-save", str(tmp_path / "sg.npz"))
    assert code == 0, err
    obj = json.loads(out)
    e = obj["sg_rel_error"]
    assert len(e) == 4 and all(b < a for a, b in zip(e, e[1:], strict=False)) and e[-1] < 0.3
    lobes = obj["sg_lobes"]
    assert len(lobes) == len(SGLobes.load(tmp_path / "sg.npz"))
    axes = np.array([lb["axis"] for lb in lobes])
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1, atol=1e-5)
    assert min(lb["sharpness"] for lb in lobes) > 0 and all(len(lb["amplitude"]) == 3 for lb in lobes)
    # the sun: the brightest pixel of the map, ~half of the map's power (computed here from the pixels)
    env = load_envmap(path)
    lum = env.image @ np.array([0.2126, 0.7152, 0.0722])
    r, c = np.unravel_index(np.argmax(lum), lum.shape)
    sun = env.directions()[r, c]
    power = (lum * env.solid_angles()).sum()
    assert obj["peaks"], "the sun was not detected"
    p = obj["peaks"][0]
    assert math.degrees(math.acos(min(1.0, float(np.dot(p["direction"], sun))))) < 1.0
    assert np.dot(p["power"], [0.2126, 0.7152, 0.0722]) > 0.4 * power
    assert 1e-5 < p["solid_angle"] < 1e-3 and len(p["lobes"]) >= 1


def test_sg_table_on_uffizi(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    code, out, err = _run(capsys, "light", str(shared_data / "envmaps" / "uffizi.hdr"), "--order", "1", "--sg",
                          "--sg-levels", "2")
    assert code == 0, err
    assert "SG lighting" in out and "peaks" in out and "rel. residual" in out


def test_sg_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                monkeypatch: pytest.MonkeyPatch) -> None:
    write_pfm(tmp_path / "ok.pfm", np.ones((8, 16, 3), np.float32))
    write_pfm(tmp_path / "black.pfm", np.zeros((8, 16, 3), np.float32))
    cases = [(("--sg-levels", "8"), "--sg-levels"), (("--sg-threshold", "1.5"), "--sg-threshold"),
             (("--sg-save", str(tmp_path / "x.txt")), "--sg-save")]
    for argv, msg in cases:
        code, out, err = _run(capsys, "light", str(tmp_path / "ok.pfm"), "--sg", *argv)
        assert code == 2 and msg in err and err.count("\n") == 1 and out == "", err
    if importlib.util.find_spec("healpy") is not None:
        code, out, err = _run(capsys, "light", str(tmp_path / "black.pfm"), "--sg", "--json")
        assert code == 2 and "black" in err and err.count("\n") == 1, err
    monkeypatch.setitem(sys.modules, "healpy", None)  # as if the sg extra were not installed
    code, out, err = _run(capsys, "light", str(tmp_path / "ok.pfm"), "--sg")
    assert code == 2 and "prt-torch[sg]" in err and err.count("\n") == 1, err
