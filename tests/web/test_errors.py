"""A missing or malformed run asset shows a readable error on the page, never a blank canvas."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from prt_torch.web.site import ASSETS, DATA, MANIFEST, MODEL


def _site_copy(site: Path, dst: Path) -> Path:
    """Symlinks to every file of ``site`` except the assets folder's (copied: the case damages one of them)."""
    dst.mkdir()
    for p in site.iterdir():
        if p.name == ASSETS:
            (dst / ASSETS).mkdir()
            for a in p.iterdir():
                (dst / ASSETS / a.name).write_bytes(a.read_bytes())
        else:
            os.symlink(p.resolve(), dst / p.name)
    return dst


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


CASES = {
    "manifest_missing": (lambda a: (a / MANIFEST).unlink(), ["manifest", "missing", "404"]),
    "manifest_malformed": (lambda a: (a / MANIFEST).write_text('{"format": "prt_torch.web/1", '), ["malformed"]),
    "data_truncated": (lambda a: _truncate(a / DATA), [DATA, "bytes"]),
    "model_missing": (lambda a: (a / MODEL).unlink(), ["visibility model", "missing"]),
    "model_garbage": (lambda a: (a / MODEL).write_bytes(b"not an onnx graph" * 10),
                      ["visibility model", "onnxruntime"]),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_broken_asset_shows_a_readable_error(case: str, checked_site: tuple[Path, Any], browser: Any,
                                             tmp_path: Path) -> None:
    from prt_torch.web.serve import SiteServer

    damage, words = CASES[case]
    site = _site_copy(checked_site[0], tmp_path / "site")
    damage(site / ASSETS)
    with SiteServer(site) as srv:
        ps = browser.open(srv.url)
        try:
            assert ps.wait_ready(timeout_ms=30000) is False, "the page started on a broken asset"
            el = ps.page.locator("#error")
            assert el.is_visible(), "no error shown: a blank canvas"
            text = el.inner_text()
            assert text.startswith("The player could not start")
            assert all(w.lower() in text.lower() for w in words), text
            assert len(text) < 2000
        finally:
            ps.page.close()
