"""``prt web RUN --check --json``: the page's frames against the Python player's, in headless Chromium."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any


def test_check_reports_page_equal_to_python_player(checked_site: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    site, result = checked_site
    for key in ("psnr_vs_player", "console_errors", "ms_per_frame", "visibility_rel_err", "frames", "ok"):
        assert key in result
    # artifacts: the difference images, kept under this test's tmp dir
    for f in result["frames"]:
        shutil.copy(f["diff_image"], tmp_path / Path(f["diff_image"]).name)
        assert f["mask_pixels"] > 500, "the character barely shows in the frame"
    assert result["console_errors"] == []
    assert result["psnr_vs_player"] >= 35.0, result["frames"]
    assert result["visibility_rel_err"] <= 1e-4
    assert result["ms_per_frame"] > 0 and result["ok"] is True
    assert len({f["brdf"] for f in result["frames"]}) == 2  # the second case swaps the BRDF and turns the light


def test_two_browsers_at_once_share_one_playwright_driver(chromium: str, browser) -> None:
    """A caller's browser and ``prt web --check``'s own are open at once in one thread (they failed with 'Sync API
    inside the asyncio loop' in that order); closing the second leaves the first usable."""
    from prt_torch.web.check import Browser

    second = Browser(chromium)
    try:
        for b in (browser, second):
            page = b.browser.new_page()
            page.set_content("<p id='x'>prt</p>")
            assert page.inner_text("#x") == "prt"
            page.close()
    finally:
        second.close()
    page = browser.browser.new_page()
    page.set_content("<p id='x'>still</p>")
    assert page.inner_text("#x") == "still"
    page.close()
