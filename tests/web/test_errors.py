"""A missing, truncated, damaged or wrong-version site file shows ONE readable error on the page (the visible
``#error`` box, naming the file and what is wrong with it), never a blank canvas or only a console message."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import pytest

from prt_torch.web.site import ASSETS, DATA, LATENT_MODEL, MANIFEST, MODEL, PEAKS_MODEL, SITE_FORMAT


def site_copy(site: Path, dst: Path) -> Path:
    """A copy of ``site`` made of hard links (the server refuses symlinks out of the site), the assets folder's files
    copied (a case damages one of them in place)."""
    shutil.copytree(site, dst, copy_function=_link_or_copy, ignore=shutil.ignore_patterns("check", ASSETS))
    shutil.copytree(site / ASSETS, dst / ASSETS)
    return dst


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:  # another file system
        shutil.copy2(src, dst)


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _set_format(site: Path, fmt: str) -> None:
    p = site / ASSETS / MANIFEST
    p.write_text(json.dumps({**json.loads(p.read_text()), "format": fmt}))


def _flip_byte(p: Path) -> None:
    raw = bytearray(p.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    p.write_bytes(bytes(raw))


def _stale_model(site: Path, raw: bytes, file: str = MODEL, key: str = "model") -> None:
    """A model that is not an ONNX graph, with a manifest that agrees with it (size and sha256)."""
    (site / ASSETS / file).write_bytes(raw)
    p = site / ASSETS / MANIFEST
    m = json.loads(p.read_text())
    m[key].update(bytes=len(raw), sha256=hashlib.sha256(raw).hexdigest())
    p.write_text(json.dumps(m))


WASM = "vendor/ort/ort-wasm-simd-threaded.wasm"

#: the page that plays the whole visibility graph per frame (an export without latent.onnx plays it too); the
#: default page of the tiny run decodes on the GPU from latent.onnx and loads the visibility graph only on demand
VIS_PAGE = "?decode=cpu"

#: damage of the site folder -> words the one error shown must contain (, the page's query)
CASES = {
    "manifest_missing": (lambda s: (s / ASSETS / MANIFEST).unlink(), ["manifest", "missing", "404"]),
    "manifest_malformed": (lambda s: (s / ASSETS / MANIFEST).write_text('{"format": "prt_torch.web/1", '),
                           ["malformed"]),
    "wrong_version": (lambda s: _set_format(s, "prt_torch.web/2"),
                      ["manifest", '"prt_torch.web/2"', f'"{SITE_FORMAT}"', "re-run `prt web`"]),
    "data_truncated": (lambda s: _truncate(s / ASSETS / DATA), [DATA, "bytes"]),
    "data_missing": (lambda s: (s / ASSETS / DATA).unlink(), ["character data", DATA, "missing", "404"]),
    "model_missing": (lambda s: (s / ASSETS / MODEL).unlink(), ["visibility model", "missing"], VIS_PAGE),
    "model_truncated": (lambda s: _truncate(s / ASSETS / MODEL), ["visibility model", MODEL, "truncated"], VIS_PAGE),
    "model_corrupt": (lambda s: _flip_byte(s / ASSETS / MODEL), ["visibility model", MODEL, "sha256"], VIS_PAGE),
    "model_garbage": (lambda s: _stale_model(s, b"not an onnx graph" * 10), ["visibility model", "onnxruntime"],
                      VIS_PAGE),
    "latent_missing": (lambda s: (s / ASSETS / LATENT_MODEL).unlink(), ["latent model", LATENT_MODEL, "missing"]),
    "latent_corrupt": (lambda s: _flip_byte(s / ASSETS / LATENT_MODEL), ["latent model", LATENT_MODEL, "sha256"]),
    "latent_garbage": (lambda s: _stale_model(s, b"not an onnx graph" * 10, LATENT_MODEL, "decode"),
                       ["latent model", "onnxruntime"]),
    "peak_model_missing": (lambda s: (s / ASSETS / PEAKS_MODEL).unlink(),
                           ["peak visibility model", PEAKS_MODEL, "missing", "404"]),
    "peak_model_corrupt": (lambda s: _flip_byte(s / ASSETS / PEAKS_MODEL), ["peak visibility model", "sha256"]),
    "wasm_missing": (lambda s: (s / WASM).unlink(), ["onnxruntime-web", WASM, "missing", "404"]),
    "script_missing": (lambda s: (s / "vendor/three/three.module.js").unlink(),
                       ["vendor/three/three.module.js", "missing", "404"]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_broken_asset_shows_a_readable_error(case: str, checked_site: tuple[Path, Any], browser: Any,
                                             tmp_path: Path) -> None:
    from prt_torch.web.serve import SiteServer

    damage, words, *query = CASES[case]
    site = site_copy(checked_site[0], tmp_path / "site")
    damage(site)
    with SiteServer(site) as srv:
        ps = browser.open(srv.url + (query[0] if query else ""))
        try:
            assert ps.wait_ready(timeout_ms=30000) is False, "the page started on a broken asset"
            alerts = ps.page.locator("[role=alert]:visible")
            n = alerts.count()
            assert n == 1, "no error shown: a blank canvas" if n == 0 else alerts.all_inner_texts()
            el = ps.page.locator("#error")
            assert el.is_visible()
            text = el.inner_text()
            assert text.startswith("The player could not start:") and text.count("could not start") == 1, text
            assert all(w.lower() in text.lower() for w in words), text
            assert len(text) < 600 and text.count("\n") <= 4, text  # one message, not a stack trace
            assert ps.page.evaluate("window.prt.error") in text
            assert ps.page.locator("#stats").inner_text() == "error"
        finally:
            ps.page.close()
