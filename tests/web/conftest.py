"""Session fixtures of the browser tests: the tiny run (tests/export/pipeline.py), its site written and checked
ONCE by ``prt web --check --json`` (the command the tests use), and one headless Chromium page on it.

Every browser test skips with one line when no Chromium can be found or the ``playwright`` package is missing
(scripts/setup.sh installs both where it runs as root); a missing ``web/node_modules`` is an error (setup runs
``npm ci``).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.export.pipeline import build_tiny_run


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="session")
def chromium() -> str:
    from prt_torch.errors import PrtError
    from prt_torch.web.check import find_chromium

    try:
        import playwright  # noqa: F401
    except ImportError:
        pytest.skip("browser tests: the playwright package is not installed (pip install -e '.[web]')")
    try:
        return find_chromium()
    except PrtError as exc:
        pytest.skip(f"browser tests: {exc}")


@pytest.fixture(scope="session")
def checked_site(tiny_run: Path, chromium: str,
                 tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """``(site dir, result)`` of ``prt web TINY --out SITE --check --json`` (artifacts under SITE/check)."""
    from prt_torch.cli import main

    site = tmp_path_factory.mktemp("web") / "site"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["web", str(tiny_run), "--out", str(site), "--check", "--json", "--chromium", chromium])
    result = json.loads(buf.getvalue())
    assert rc in (0, 1), f"prt web --check exited {rc}"
    return site, result


@pytest.fixture(scope="session")
def browser(chromium: str):
    from prt_torch.web.check import Browser

    b = Browser(chromium)
    yield b
    b.close()


@pytest.fixture(scope="session")
def site_url(checked_site: tuple[Path, dict[str, Any]]):
    from prt_torch.web.serve import SiteServer

    with SiteServer(checked_site[0]) as srv:
        yield srv.url


@pytest.fixture(scope="session")
def page(browser: Any, site_url: str):
    """The tiny run's page, started and paused (scripted through ``window.prt``)."""
    ps = browser.open(site_url + "?paused")
    assert ps.wait_ready(), f"page failed to start: {ps.page.evaluate('window.prt.error')}"
    yield ps
    ps.page.close()


@pytest.fixture(scope="session")
def player(tiny_run: Path, checked_site: tuple[Path, dict[str, Any]]):
    """The Python player of the tiny run with the site's sky tone map (the page's reference): its SH path
    (:meth:`~prt_torch.player.player.Player.shade`) shades the whole sky, as the page does with its peaks off."""
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.player import Player
    from prt_torch.player.tonemap import ToneMap
    from prt_torch.web.site import read_manifest

    m = read_manifest(checked_site[0])
    tm = m["lights"][0]["tonemap"]
    p = Player(tiny_run, threads=1, graph="split", window_size=(480, 640),
               exposure=ToneMap(tm["exposure"], tm["white"]))
    p.lighting = load_lighting(None, p.order)  # the whole lighting on the SH path (a peak-splitting player: too)
    p.rotate_light(0.0)
    yield p
    p.close()


@pytest.fixture(scope="session")
def compiled(tiny_run: Path, checked_site: tuple[Path, dict[str, Any]]):
    """The Python player's compiled CPU path (the reference of the GPU decode) under the whole sky."""
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.player import Player

    p = Player(tiny_run, threads=1, graph="compiled")
    p.lighting = load_lighting(None, p.order)
    p.rotate_light(0.0)
    yield p
    p.close()


@pytest.fixture(scope="session")
def decode(checked_site: tuple[Path, dict[str, Any]], player: Any) -> dict[str, Any]:
    """The site's GPU decode data as the page reads it: manifest entry, bases (V, K + 1, 4T) float32, rows (V, 2)."""
    from prt_torch.web.site import ASSETS, DATA, read_manifest

    m = read_manifest(checked_site[0])
    d = m["decode"]
    assert d is not None and d["basis_dtype"] == "float16", "the tiny run's site must decode on the GPU"
    raw = (checked_site[0] / ASSETS / DATA).read_bytes()

    def array(name: str) -> np.ndarray:
        e = m["data"]["arrays"][name]
        return np.frombuffer(raw, np.dtype(e["dtype"]), count=int(np.prod(e["shape"])), offset=e["offset"]) \
            .reshape(e["shape"])

    v = m["n_vertices"]
    basis = array(d["basis"]).astype(np.float32).reshape(v, d["k_max"] + 1, -1)
    return {"entry": d, "basis": basis, "rows": array(d["rows"]).astype(np.int64)}
