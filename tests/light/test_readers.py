"""HDR readers vs independent references: a pure-python RGBE decoder, arrays we wrote ourselves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR  # a base dependency: .exr reading is part of every install
import pytest

from prt_torch.errors import PrtError
from prt_torch.light.envmap import load_envmap
from prt_torch.light.readers import read_hdr_image, read_pfm, write_pfm
from tests.tolerance import assert_bitwise


def _decode_rgbe(path: Path) -> np.ndarray:
    """Independent Radiance RGBE decoder (flat and new-style RLE scanlines), (H, W, 3) RGB float32."""
    data = path.read_bytes()
    pos = 0
    lines = []
    while True:  # header lines up to the blank line, then the resolution line
        end = data.index(b"\n", pos)
        line = data[pos:end]
        pos = end + 1
        lines.append(line)
        if line.startswith(b"-Y"):
            break
    _, h, _, w = lines[-1].split()
    h, w = int(h), int(w)
    out = np.zeros((h, w, 4), dtype=np.uint8)
    for y in range(h):
        if 8 <= w < 32768 and data[pos] == 2 and data[pos + 1] == 2 and not (data[pos + 2] & 0x80):
            pos += 4
            for c in range(4):
                x = 0
                while x < w:
                    n = data[pos]
                    pos += 1
                    if n > 128:
                        out[y, x:x + n - 128, c] = data[pos]
                        pos += 1
                        x += n - 128
                    else:
                        out[y, x:x + n, c] = np.frombuffer(data[pos:pos + n], dtype=np.uint8)
                        pos += n
                        x += n
        else:
            out[y] = np.frombuffer(data[pos:pos + 4 * w], dtype=np.uint8).reshape(w, 4)
            pos += 4 * w
    e = out[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return (out[..., :3] * scale[..., None]).astype(np.float32)  # (m + 0.5) convention differs: see test


def _asym_image(h: int = 6, w: int = 10) -> np.ndarray:
    """A test image whose rows, columns and channels all differ."""
    r = np.arange(h)[:, None] + 1.0
    c = np.arange(w)[None, :] + 1.0
    return np.stack([r * 10 + c, 2.0 * c + 0.5 * r, 0.25 * r * c], axis=-1).astype(np.float32)


def test_uffizi_matches_independent_rgbe_decoder(shared_data: Path) -> None:
    path = shared_data / "envmaps" / "uffizi.hdr"
    ours = read_hdr_image(path)
    ref = _decode_rgbe(path)
    assert ours.shape == (128, 256, 3) and ours.dtype == np.float32
    # OpenCV decodes RGBE as m * 2^(e-136) like the reference (stb adds no 0.5 offset either)
    np.testing.assert_allclose(ours, ref, rtol=1e-6, atol=0)
    # top rows (sky, up) are brighter than the bottom rows: row 0 is the top of the image
    assert ours[: 64].mean() > 5 * ours[64:].mean()


def test_hdr_roundtrip_orientation_and_channels(tmp_path: Path) -> None:
    import cv2

    img = _asym_image()
    p = tmp_path / "a.hdr"
    assert cv2.imwrite(str(p), np.ascontiguousarray(img[..., ::-1]))  # cv2 writes BGR
    got = read_hdr_image(p)
    np.testing.assert_allclose(got, img, rtol=1.0 / 64)  # RGBE keeps ~8 mantissa bits
    np.testing.assert_allclose(got, _decode_rgbe(p), rtol=1e-6)


def test_exr_rgb_half_and_luminance(tmp_path: Path) -> None:
    img = _asym_image()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    p = tmp_path / "rgb.exr"
    with OpenEXR.File(header, {c: np.ascontiguousarray(img[..., i]) for i, c in enumerate("RGB")}) as f:
        f.write(str(p))
    assert_bitwise(read_hdr_image(p), img, why='file round trip of float32 values')
    ph = tmp_path / "half.exr"
    with OpenEXR.File(header, {"RGB": img.astype(np.float16)}) as f:
        f.write(str(ph))
    assert_bitwise(read_hdr_image(ph), img.astype(np.float16).astype(np.float32),
                   why='file round trip of float16 values')
    py = tmp_path / "y.exr"
    with OpenEXR.File(header, {"Y": np.ascontiguousarray(img[..., 0])}) as f:
        f.write(str(py))
    assert_bitwise(read_hdr_image(py), np.repeat(img[..., :1], 3, axis=2), why='file round trip of float32 values')


@pytest.mark.parametrize("little", [True, False])
def test_pfm_hand_written_file(tmp_path: Path, little: bool) -> None:
    img = _asym_image()
    h, w = img.shape[:2]
    # independent writer: header, then rows bottom-to-top
    body = np.ascontiguousarray(img[::-1], dtype="<f4" if little else ">f4").tobytes()
    p = tmp_path / "a.pfm"
    p.write_bytes(f"PF\n{w} {h}\n{-1.0 if little else 1.0}\n".encode() + body)
    assert_bitwise(read_pfm(p), img, why='file round trip of float32 values')
    q = tmp_path / "b.pfm"
    write_pfm(q, img, little_endian=little)
    assert q.read_bytes() == p.read_bytes()
    g = tmp_path / "g.pfm"
    g.write_bytes(f"Pf\n{w} {h}\n-1.0\n".encode() + np.ascontiguousarray(img[::-1, :, 1], dtype="<f4").tobytes())
    assert_bitwise(read_pfm(g), np.repeat(img[..., 1:2], 3, axis=2), why='file round trip of float32 values')


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="unknown HDR image format"):
        read_hdr_image(tmp_path / "x.png")
    with pytest.raises(PrtError, match="not found"):
        read_hdr_image(tmp_path / "missing.hdr")
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"this is not an image")
    with pytest.raises(PrtError, match="not a readable Radiance"):
        read_hdr_image(bad)
    badx = tmp_path / "bad.exr"
    badx.write_bytes(b"garbage")
    with pytest.raises(PrtError, match="OpenEXR"):
        read_hdr_image(badx)
    t = tmp_path / "t.pfm"
    t.write_bytes(b"PF\n4 4\n-1.0\n" + b"\0" * 20)
    with pytest.raises(PrtError, match="truncated"):
        read_pfm(t)
    h = tmp_path / "h.pfm"
    h.write_bytes(b"P6\n4 4\n255\n")
    with pytest.raises(PrtError, match="bad header"):
        read_pfm(h)


def test_nan_inf_in_envmap_rejected(tmp_path: Path) -> None:
    img = np.ones((8, 16, 3), np.float32)
    img[3, 4, 1] = np.nan
    img[5, 5, 0] = np.inf
    p = tmp_path / "nan.pfm"
    write_pfm(p, img)
    with pytest.raises(PrtError, match=r"NaN or Inf in 2 pixel"):
        load_envmap(p)
