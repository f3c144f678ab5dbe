"""Malformed HDR/EXR/PFM files: absurd headers refused before allocating (with the estimate), truncated or
non-finite data refused, library chatter silenced; a property-style generator mutates small valid files."""

from __future__ import annotations

import re
import struct
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prt_torch.errors import PrtError, PrtWarning
from prt_torch.light.envmap import load_envmap
from prt_torch.light.readers import MAX_IMAGE_BYTES, read_hdr_image, read_pfm, write_pfm
from tests.rig.test_gltf_malformed import time_limit
from tests.tolerance import assert_bitwise


def _image(h: int = 8, w: int = 16) -> np.ndarray:
    return (np.random.default_rng(0).random((h, w, 3)) * 4 + 0.01).astype(np.float32)


def valid_bytes(suffix: str) -> bytes:
    """A small valid file of each format (RGBE RLE via OpenCV, ZIP EXR via OpenEXR, little-endian PFM)."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"v{suffix}"
        img = _image()
        if suffix == ".hdr":
            cv2.imwrite(str(p), img[..., ::-1])
        elif suffix == ".exr":
            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            with OpenEXR.File(header, {"RGB": img}) as f:
                f.write(str(p))
        else:
            write_pfm(p, img)
        return p.read_bytes()


VALID = {s: valid_bytes(s) for s in (".hdr", ".exr", ".pfm")}


def check_outcome(path: Path) -> None:
    try:
        with time_limit():
            img = read_hdr_image(path)
    except PrtError as e:
        assert str(e) and "\n" not in str(e), repr(str(e))
        return
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32 and np.isfinite(img).all()
    assert img.nbytes <= MAX_IMAGE_BYTES


def _set_pfm_header(raw: bytes, header: bytes) -> bytes:
    return header + raw[len(b"PF\n16 8\n-1\n"):]


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data(), suffix=st.sampled_from([".hdr", ".exr", ".pfm"]))
def test_mutated_images_read_or_one_line_error(data: st.DataObject, suffix: str) -> None:
    raw = bytearray(VALID[suffix])
    kind = data.draw(st.sampled_from(["truncate", "flip", "size"]))
    if kind == "truncate":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    elif kind == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    else:  # header sizes blown up (or zeroed), scale 0 / NaN / inf for PFM
        w = data.draw(st.sampled_from([0, 1, 16, 17, 40000, 2**31, 10**12]))
        h = data.draw(st.sampled_from([0, 1, 8, 9, 20000, 2**31]))
        if suffix == ".hdr":
            raw = bytearray(re.sub(rb"-Y \d+ \+X \d+", f"-Y {h} +X {w}".encode(), bytes(raw), count=1))
        elif suffix == ".pfm":
            scale = data.draw(st.sampled_from(["-1", "1", "0", "nan", "1e999", "-0.0"]))
            raw = bytearray(_set_pfm_header(bytes(raw), f"PF\n{w} {h}\n{scale}\n".encode()))
        else:
            i = raw.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
            struct.pack_into("<iiii", raw, i, 0, 0, min(w, 2**31 - 1) - 1, min(h, 2**31 - 1) - 1)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"m{suffix}"
        p.write_bytes(bytes(raw))
        check_outcome(p)


def test_valid_files_read() -> None:
    with tempfile.TemporaryDirectory() as d:
        for suffix, raw in VALID.items():
            p = Path(d) / f"ok{suffix}"
            p.write_bytes(raw)
            np.testing.assert_allclose(read_hdr_image(p), _image(), rtol=0.02, atol=0.02)


def test_huge_rgbe_header_refused_with_estimate(tmp_path: Path) -> None:
    p = tmp_path / "big.hdr"
    p.write_bytes(re.sub(rb"-Y \d+ \+X \d+", b"-Y 20000 +X 40000", VALID[".hdr"], count=1))
    with pytest.raises(PrtError, match=r"refusing a 40000x20000 image: 8\.94 GiB of float32 RGB pixels exceeds "
                                       r"the 1 GiB limit") as e:
        load_envmap(p)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("header, match", [
    (b"PF\n-16 8\n-1\n", "bad header"),
    (b"PF\n16 -8\n-1\n", "bad header"),
    (b"PF\n400000 200000\n-1\n", "refusing a 400000x200000 image: 894 GiB"),
    (b"PF\n0 8\n-1\n", "bad PFM header"),
    (b"PF\n16 8\n0\n", r"bad PFM header .*scale 0"),
    (b"PF\n16 8\nnan\n", "bad header"),
    (b"PF\n16 8\n1e999\n", r"bad PFM header .*scale inf"),
    (b"PF\n16 9\n-1\n", "truncated PFM file"),
])
def test_bad_pfm_headers(tmp_path: Path, header: bytes, match: str) -> None:
    p = tmp_path / "x.pfm"
    p.write_bytes(_set_pfm_header(VALID[".pfm"], header))
    with pytest.raises(PrtError, match=match):
        read_pfm(p)


def test_huge_exr_data_window_refused_before_reading(tmp_path: Path) -> None:
    raw = bytearray(VALID[".exr"])
    i = raw.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    struct.pack_into("<iiii", raw, i, 0, 0, 39999, 19999)
    p = tmp_path / "big.exr"
    p.write_bytes(bytes(raw))
    with time_limit(), pytest.raises(PrtError, match="refusing a 40000x20000 image: 8.94 GiB"):
        read_hdr_image(p)


def test_non_finite_pixels_refused(tmp_path: Path) -> None:
    img = _image()
    img[1, 2, 0] = np.nan
    p = tmp_path / "n.exr"
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": img}) as f:
        f.write(str(p))
    with pytest.raises(PrtError, match=r"contains NaN or Inf in 1 pixel"):
        read_hdr_image(p)
    q = tmp_path / "n.pfm"
    write_pfm(q, img)
    with pytest.raises(PrtError, match=r"contains NaN or Inf in 1 pixel"):
        read_pfm(q)


@pytest.mark.parametrize("suffix", [".exr", ".pfm"])
def test_negative_radiance_is_clamped_with_one_warning(tmp_path: Path, suffix: str) -> None:
    """PFM and EXR store negative floats; radiance cannot be negative: clamped to 0, one warning line giving the
    number of pixels with a negative channel (3 here, one with two) and the lowest value."""
    img = _image()
    img[1, 2] = [-0.5, 1.0, -2.0]
    img[3, 4, 1] = -1e-3
    img[7, 15, 0] = -0.25
    p = tmp_path / f"neg{suffix}"
    if suffix == ".exr":
        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                          {"RGB": img}) as f:
            f.write(str(p))
    else:
        write_pfm(p, img)
    with pytest.warns(PrtWarning) as record:
        got = read_hdr_image(p)
    assert [str(w.message) for w in record] == [
        f"neg{suffix}: clamped negative radiance to 0 in 3 of 128 pixel(s) (lowest value -2)"]
    # exact: the float32 pixels written and read back, clamped by the same maximum
    assert_bitwise(got, np.maximum(img, 0.0), why="clamping is exact: the positive pixels are copied")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a map without negative pixels reads without a warning
        write_pfm(tmp_path / "pos.pfm", np.maximum(img, 0.0))
        assert_bitwise(read_hdr_image(tmp_path / "pos.pfm"), got, why="file round trip of the same pixels")


@pytest.mark.parametrize("suffix, cut", [(".exr", 300), (".hdr", 200), (".exr", 0.8)])
def test_truncated_files_are_one_quiet_line(tmp_path: Path, capfd: pytest.CaptureFixture[str], suffix: str,
                                            cut: float) -> None:
    """The library chatter OpenEXR/OpenCV print for a corrupt file (stdout and stderr) is silenced."""
    raw = VALID[suffix]
    p = tmp_path / f"t{suffix}"
    p.write_bytes(raw[:len(raw) - cut] if isinstance(cut, int) else raw[:int(len(raw) * cut)])
    capfd.readouterr()
    with pytest.raises(PrtError) as e:
        read_hdr_image(p)
    out, err = capfd.readouterr()
    assert out == "" and err == "", (out, err)
    assert "\n" not in str(e.value) and ("truncated" in str(e.value) or "not a readable" in str(e.value))
