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


# ------------------------------------------------------------------------------------------ --peaks (issue 27)


def _disc_map(center: np.ndarray, radius_deg: float, radiance: list[float], h: int = 128) -> np.ndarray:
    """A uniform sky of radiance 1 plus a disc (pixel centres inside it), ``(H, 2H, 3)`` float32."""
    d = latlong_directions(h, 2 * h)
    img = np.ones((h, 2 * h, 3))
    img[d @ center >= math.cos(math.radians(radius_deg))] += radiance
    return img.astype(np.float32)


def test_peaks_json_on_a_disc_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    from prt_torch.light.envmap import latlong_solid_angles

    center = np.array([0.3, -0.5, 0.6])
    center /= np.linalg.norm(center)
    img = _disc_map(center, 5.0, [200.0, 150.0, 100.0])
    write_pfm(tmp_path / "disc.pfm", img)
    code, out, err = _run(capsys, "light", str(tmp_path / "disc.pfm"), "--peaks", "--json")
    assert code == 0 and err == "", err
    obj = json.loads(out)
    assert len(obj["peaks"]) == 1 and set(obj["peaks"][0]) == {"direction", "angular_radius_deg", "radiance"}
    p = obj["peaks"][0]
    assert math.degrees(math.acos(min(1.0, float(np.dot(p["direction"], center))))) < 180 / 128
    assert abs(p["angular_radius_deg"] - 5.0) < 0.2 * 5.0
    np.testing.assert_allclose(p["radiance"], [200.0, 150.0, 100.0], rtol=0.1)
    # peaks (closed-form disc integral) + residual power = the map's power (pixel sums here)
    map_power = np.einsum("hw,hwc->c", latlong_solid_angles(128, 256), img.astype(np.float64))
    disc = np.array(p["radiance"]) * 2 * np.pi * (1 - math.cos(math.radians(p["angular_radius_deg"])))
    np.testing.assert_allclose(disc + np.array(obj["residual_power"]), map_power, rtol=0.01)
    np.testing.assert_allclose(obj["map_power"], map_power, rtol=1e-6)
    assert max(abs(e) for e in obj["energy_rel_error"]) < 0.01 and len(obj["peak_share"]) == 1
    # the residual's SH: the uniform sky of radiance 1 (DC sqrt(4 pi), nothing else)
    res = np.array(obj["residual_coefficients"])
    assert res.shape == (9, 3)
    np.testing.assert_allclose(res[0], math.sqrt(4 * math.pi), rtol=0.01)
    assert np.abs(res[1:]).max() < 0.01 * math.sqrt(4 * math.pi)
    code, out, _ = _run(capsys, "light", str(tmp_path / "disc.pfm"), "--peaks", "3")
    assert code == 0 and "1 peak light(s) of at most 3" in out and "residual: power" in out


def test_peaks_of_the_player_sky(capsys: pytest.CaptureFixture[str]) -> None:
    from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION

    code, out, err = _run(capsys, "light", "sky", "--peaks", "--json")
    assert code == 0, err
    obj = json.loads(out)
    assert len(obj["peaks"]) == 1
    p = obj["peaks"][0]
    sun = np.array(DEFAULT_SUN_DIRECTION) / np.linalg.norm(DEFAULT_SUN_DIRECTION)
    np.testing.assert_allclose(p["direction"], sun, atol=1e-12)
    assert p["angular_radius_deg"] == pytest.approx(0.265)
    np.testing.assert_allclose(obj["peak_power"][0], DEFAULT_SUN_COLOR, rtol=1e-9)
    code, out, _ = _run(capsys, "light", "sky", "--peaks", "1", "--sun-radius", "2", "--json")
    assert code == 0 and json.loads(out)["peaks"][0]["angular_radius_deg"] == pytest.approx(2.0)
    from tests.torchfree import run_cli_without_torch

    run_cli_without_torch(["light", "sky", "--peaks", "--json"])  # the sky's split is numpy only


def test_peaks_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_pfm(tmp_path / "ok.pfm", np.ones((8, 16, 3), np.float32))
    ok = str(tmp_path / "ok.pfm")
    cases = [
        (("sky", "--peaks", "5"), "--peaks must be an integer in 1..4, got '5'"),
        (("sky", "--peaks", "0"), "--peaks must be an integer in 1..4"),
        (("sky", "--peaks", "-1"), "--peaks must be an integer in 1..4"),
        (("sky", "--peaks", "two"), "--peaks must be an integer in 1..4, got 'two'"),
        ((ok, "--peaks", "--sg"), "without --lobes / --sg"),
        ((ok, "--peaks", "--sun-radius", "1"), "--sun-radius is the procedural sky's"),
        ((ok, "--sun-radius", "1"), "--sun-radius goes with --peaks"),
        (("sky", "--peaks", "--sun-radius", "0"), "sun angular radius"),
    ]
    for argv, msg in cases:
        code, out, err = _run(capsys, "light", *argv)
        assert code == 2, (argv, err)
        assert err.startswith("error: ") and msg in err and err.count("\n") == 1, err
        assert "Traceback" not in err and out == ""


@pytest.mark.parametrize(("name", "elevation"), [("spiaggia_di_mondello_1k.hdr", None), ("quarry_01_1k.hdr", 10.0)])
def test_peaks_of_the_shared_maps(shared_data: Path, capsys: pytest.CaptureFixture[str], name: str,
                                  elevation: float | None) -> None:
    """The sun of each shared outdoor map: at its brightest pixel, sun-sized (issue 27: mondello's is 6.8e-5 sr),
    about half of the luminous power; energy kept."""
    pytest.importorskip("healpy", reason="the sg extra (healpy) is not installed")
    from prt_torch.light.envmap import load_envmap

    path = shared_data / "envmaps" / name
    code, out, err = _run(capsys, "light", str(path), "--peaks", "--json")
    assert code == 0, err
    obj = json.loads(out)
    env = load_envmap(path)
    lum = env.image @ np.array([0.2126, 0.7152, 0.0722])
    r, c = np.unravel_index(np.argmax(lum), lum.shape)
    p = obj["peaks"][0]
    assert math.degrees(math.acos(min(1.0, float(np.dot(p["direction"], env.directions()[r, c]))))) < 0.5
    assert 2e-5 < obj["peak_solid_angle_sr"][0] < 2e-4 and obj["peak_share"][0] > 0.4
    assert max(abs(e) for e in obj["energy_rel_error"]) < 0.01
    if elevation is not None:
        assert math.degrees(math.asin(p["direction"][2])) == pytest.approx(elevation, abs=2.0)
