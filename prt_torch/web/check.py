"""``prt web RUN --check``: the page in headless Chromium against the Python player, frame by frame.

For each fixed case (clip, frame, light angle, BRDF; the procedural sky and the tone map ``prt web`` fixed
for it) the page renders one frame (``window.prt.setState`` / ``render`` / ``readPixels``) and the Python player
(:class:`prt_torch.player.Player`, same run, same float32 joint transforms, same camera) renders the same
frame; image PSNR over the pixels the character fully covers (:mod:`prt_torch.scoring`'s mask and PSNR
rule); the difference image ``4 x |page - player|`` is written next to both frames. The cases follow the
player's own peaks (a player that splits the sky's sun off is compared with the page's peaks on, one that does not
with them off); a site whose sky has peaks is also checked with them on against :mod:`prt_torch.web.peaks`
(``peak_frames``: the residual's player shading plus the peak term, the same PSNR rule). The visibility that
onnxruntime-web computes for those poses is compared with onnxruntime's (relative L2; for int8 ``MatMulNBits``
graphs with the float32 compute onnxruntime-web implements, see :func:`fp32_compute_session`). ``ms_per_frame``
is the median of the page's own step timings (posing + wasm inference + upload + draw, the draw waited for with
``gl.finish``) over a few steps; ``raf_fps_playing`` the frames/s of the page's own playing loop.

Chromium: ``PRT_CHROMIUM``, else ``chromium`` / ``chromium-browser`` / ``google-chrome`` on PATH (Debian's
``chromium`` package), driven by Playwright (the ``playwright`` Python package; no browser download).
"""

from __future__ import annotations

import base64
import os
import shutil
import statistics
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check

#: flags for headless Chromium on a machine without a GPU or network
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-background-timer-throttling", "--disable-renderer-backgrounding")
#: pass marks of the check
MIN_PSNR_DB = 35.0
MAX_VIS_REL_ERR = 1e-4
#: console messages that are not errors of the page (Chromium's own performance notes)
IGNORED_CONSOLE = ("GPU stall due to ReadPixels",)


def find_chromium(explicit: str | None = None) -> str:
    """Path of a Chromium executable (one-line error naming the install step when there is none)."""
    for c in (explicit, os.environ.get("PRT_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if c:
            p = shutil.which(c) or (c if Path(c).is_file() else None)
            if p:
                return p
    raise PrtError("no Chromium found: install Debian's `chromium` package (scripts/setup.sh does, as root) "
                   "or set PRT_CHROMIUM")


@dataclass
class PageSession:
    """A loaded page and what it logged."""

    page: Any
    console: list[tuple[str, str]]

    @property
    def errors(self) -> list[str]:
        return [text for kind, text in self.console if kind in ("error", "pageerror")
                and not any(s in text for s in IGNORED_CONSOLE)]

    def wait_ready(self, timeout_ms: int = 60000) -> bool:
        """Wait until the page started (True) or showed its error (False)."""
        self.page.wait_for_function("window.prt && window.prt.ready", timeout=timeout_ms)
        return bool(self.page.evaluate("window.prt.ready.then(a => a !== null)"))

    def frame(self, state: dict[str, Any]) -> tuple[np.ndarray, dict[str, float]]:
        """Set ``state`` (``window.prt.setState``), render one step; ``(H, W, 3)`` uint8 image, step timings. As the
        Python player draws its frames: the fixed camera (its ``pose`` eye), no floor and the site's tone map of the
        lighting, unless ``state`` says ``"camera": "follow"`` / ``"floor": True`` / ``"tonemap": {...}`` (a state
        of an earlier frame does not leak into this one: the page keeps what it was last told)."""
        state = {"camera": "fixed", "floor": False, "tonemap": None, **state}
        self.page.evaluate("s => window.prt.setState(s)", state)
        stats = self.page.evaluate("window.prt.render()")
        px = self.page.evaluate("window.prt.readPixels()")
        rgba = np.frombuffer(base64.b64decode(px["rgba"]), np.uint8).reshape(px["height"], px["width"], 4)
        return np.ascontiguousarray(rgba[::-1, :, :3]), stats


class _Driver:
    """One Playwright driver per thread, shared by every :class:`Browser` of that thread (reference-counted).

    Playwright's sync API runs its event loop inside the calling thread: a second ``sync_playwright().start()``
    while one is alive fails ("Sync API inside the asyncio loop"), so two browsers open at once - a caller's and
    ``prt web --check``'s own - must share it."""

    _local = threading.local()

    @classmethod
    def acquire(cls) -> Any:
        st = cls._local.__dict__
        if st.get("users", 0) == 0:
            try:
                from playwright.sync_api import sync_playwright
            except ImportError:
                raise PrtError("the `playwright` Python package is missing: pip install -e '.[dev]'") from None
            st["pw"] = sync_playwright().start()
        st["users"] = st.get("users", 0) + 1
        return st["pw"]

    @classmethod
    def release(cls) -> None:
        st = cls._local.__dict__
        st["users"] -= 1
        if st["users"] == 0:
            pw = st.pop("pw")
            pw.stop()


class Browser:
    """Headless Chromium through Playwright (one browser; pages opened with :meth:`open`)."""

    def __init__(self, chromium: str | None = None) -> None:
        self._pw = _Driver.acquire()
        try:
            self.browser = self._pw.chromium.launch(executable_path=find_chromium(chromium), args=list(CHROMIUM_FLAGS),
                                                    headless=True)
        except Exception:
            _Driver.release()
            raise

    def open(self, url: str, width: int = 1100, height: int = 560) -> PageSession:
        page = self.browser.new_page(viewport={"width": width, "height": height})
        console: list[tuple[str, str]] = []
        page.on("console", lambda m: console.append((m.type, m.text)))
        page.on("pageerror", lambda e: console.append(("pageerror", str(e))))
        page.goto(url)
        return PageSession(page, console)

    def close(self) -> None:
        try:
            self.browser.close()
        finally:
            _Driver.release()


@contextmanager
def served_page(site: str | os.PathLike[str], chromium: str | None = None, query: str = "?paused",
                browser: Browser | None = None) -> Iterator[PageSession]:
    """Serve ``site`` on 127.0.0.1, open it in headless Chromium (``browser``, or one started here), yield the page."""
    from prt_torch.web.serve import SiteServer

    with SiteServer(site) as srv:
        b = Browser(chromium) if browser is None else browser
        ps = None
        try:
            ps = b.open(srv.url + query)
            yield ps
        finally:
            if ps is not None:
                ps.page.close()
            if browser is None:
                b.close()


def default_cases(manifest: dict[str, Any]) -> list[dict[str, Any]]:
    """Two fixed cases: the middle frame of the first clip (default BRDF, light as written) and a later frame of
    the last clip under another BRDF with the light rotated by 60 degrees."""
    clips = [c for c in manifest["clips"] if not c["name"].startswith("motion:")]  # the character's own clips
    brdfs = [r["name"] for r in manifest["rpos"] if r["name"] != "material"]
    first = clips[0]
    last = clips[-1]
    other = next((b for b in brdfs if b != manifest["default_brdf"]), manifest["default_brdf"])
    return [{"clip": first["name"], "frame": first["frames"] // 2, "brdf": manifest["default_brdf"], "lightAngle": 0.0},
            {"clip": last["name"], "frame": (2 * last["frames"]) // 3, "brdf": other,
             "lightAngle": float(np.radians(60.0))}]


def fp32_compute_session(path: Path) -> Any:
    """An onnxruntime session of the graph with every ``MatMulNBits`` node at ``accuracy_level`` 0, or ``None`` when
    the graph has none at another level.

    Native onnxruntime runs an int8-weight MatMulNBits at accuracy level 4 with its activations rounded to int8;
    onnxruntime-web's wasm kernel ignores the level and computes in float32 (measured: 1e-8 from native at level 0,
    4e-4 from native at level 4 on an int8 export). The page is therefore compared with native onnxruntime computing
    the same float32 arithmetic; the gap to the player's own graph is reported beside it."""
    import onnxruntime as ort

    try:
        import onnx
    except ImportError:  # without the export extra: compare with the player's graph as it is
        return None
    m = onnx.load(str(path))
    changed = False
    for n in m.graph.node:
        if n.op_type == "MatMulNBits":
            for a in n.attribute:
                if a.name == "accuracy_level" and a.i != 0:
                    a.i = 0
                    changed = True
    if not changed:
        return None
    return ort.InferenceSession(m.SerializeToString(), providers=["CPUExecutionProvider"])


def check_site(site: str | os.PathLike[str], run: str | os.PathLike[str], chromium: str | None = None,
               artifacts: str | os.PathLike[str] | None = None, cases: list[dict[str, Any]] | None = None,
               timing_steps: int = 8, play_seconds: float = 2.0, browser: Browser | None = None) -> dict[str, Any]:
    """Compare the page with the Python player (see the module docstring). Returns the result dict:
    ``psnr_vs_player`` (dB, the minimum over cases), ``console_errors``, ``ms_per_frame``, ``visibility_rel_err``,
    per-case ``frames``, ``ok``; images under ``artifacts`` when given."""
    from prt_torch.player.player import Player
    from prt_torch.player.tonemap import ToneMap
    from prt_torch.scoring.images import ImageRenderer, player_camera
    from prt_torch.scoring.statistics import image_psnr
    from prt_torch.scoring.strips import abs_diff_image, write_png
    from prt_torch.web.site import read_manifest, site_local

    m = read_manifest(site)
    cases = cases if cases is not None else default_cases(m)
    light = m["lights"][0]
    check(light["name"] == "sky", "the site's first lighting preset must be the player's sky")
    out_dir = Path(artifacts) if artifacts is not None else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    h, w = int(m["camera"]["height"]), int(m["camera"]["width"])
    player = Player(run, brdf=cases[0]["brdf"], threads=1, graph="split", window_size=(h, w))
    # the page's peaks as the player plays them (a player that splits the sky's sun off: peaks on)
    player_peaks = bool(getattr(getattr(player, "peaks", None), "peaks", None)) and bool(light.get("peaks"))
    tm_entry = light["peaks"]["tonemap"] if player_peaks else light["tonemap"]
    tm = player.exposure = ToneMap(tm_entry["exposure"], tm_entry["white"])
    results: list[dict[str, Any]] = []
    try:
        ch = player.character
        masker = ImageRenderer(ch.rest_vertices, ch.faces, player_camera(ch, (h, w)))
        with served_page(site, chromium, browser=browser) as ps:
            check(ps.wait_ready(), f"the page failed to start: {ps.page.evaluate('window.prt.error')}")
            feats_all, vis_err_num, vis_err_den, vp_num = [], 0.0, 0.0, 0.0
            fp32 = fp32_compute_session(player.bundle.run.graph_path("visibility"))
            for i, case in enumerate(cases):
                local = site_local(ch, case["clip"], case["frame"])
                player.set_brdf(case["brdf"])
                player.light_angle = 0.0
                player.rotate_light(case["lightAngle"])
                state, rad = player.compute(local)
                ref = player.render_frame(state, rad)
                mask = masker.mask(state.positions_vx3(0))
                img, _ = ps.frame({**case, "light": "sky", "playing": False, "unshadowed": False, "peaks": player_peaks,
                                   "tonemap": {"exposure": tm.exposure, "white": tm.white}})
                check(img.shape == ref.shape, f"page frame {img.shape} vs player frame {ref.shape}")
                psnr = image_psnr(img, ref, mask)
                feats_all.append(state.features)
                vis_page = np.asarray(ps.page.evaluate("f => window.prt.visibility(f, 1)",
                                                       state.features.reshape(-1).astype(float).tolist()), np.float64)
                vis_player = player.visibility(state.features).astype(np.float64).reshape(-1)
                vis_ref = vis_player if fp32 is None else \
                    fp32.run(None, {"pose": state.features})[0].astype(np.float64).reshape(-1)
                vis_err_num += float(np.sum((vis_page - vis_ref) ** 2))
                vis_err_den += float(np.sum(vis_ref ** 2))
                vp_num += float(np.sum((vis_page - vis_player) ** 2))
                entry = {**case, "psnr": float(psnr), "mask_pixels": int(mask.sum())}
                if out_dir is not None:
                    stem = f"case{i}_{case['clip']}_{case['frame']}_{case['brdf']}"
                    write_png(out_dir / f"{stem}_page.png", img)
                    write_png(out_dir / f"{stem}_player.png", ref)
                    write_png(out_dir / f"{stem}_diff.png", abs_diff_image(img, ref))
                    entry["diff_image"] = str(out_dir / f"{stem}_diff.png")
                results.append(entry)
            peaks = _peak_cases(ps, player, m, site, cases, masker, out_dir) if light.get("peaks") else []
            steps = []
            ps.frame({"clip": cases[0]["clip"], "frame": 0, "brdf": cases[0]["brdf"], "lightAngle": 0.0,
                      "syncGpu": True, "peaks": bool(light.get("peaks"))})
            c0 = next(c for c in m["clips"] if c["name"] == cases[0]["clip"])
            for k in range(timing_steps):
                ps.page.evaluate("s => window.prt.setState(s)", {"frame": k % c0["frames"]})
                steps.append(ps.page.evaluate("window.prt.render()"))
            raf_fps = None
            if play_seconds > 0:  # the page's own requestAnimationFrame loop, playing
                ps.page.evaluate("s => window.prt.setState(s)", {"playing": True, "paused": False, "syncGpu": False})
                ps.page.wait_for_timeout(int(play_seconds * 1000))
                raf_fps = float(ps.page.evaluate("window.prt.stats()")["fps"])
                ps.page.evaluate("s => window.prt.setState(s)", {"playing": False, "paused": True})
            wasm_threads = int(ps.page.evaluate("window.prt.wasmThreads"))
            gl_renderer = str(ps.page.evaluate(
                "(() => { const gl = window.prt.app.renderer.getContext(); "
                "const e = gl.getExtension('WEBGL_debug_renderer_info'); "
                "return e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER); })()"))
            errors = ps.errors
        masker.close()
    finally:
        player.close()
    med = {key: float(statistics.median(s[key] for s in steps)) for key in ("step_ms", "pose_ms", "visibility_ms",
                                                                              "render_ms")}
    psnr_min = min(r["psnr"] for r in results + peaks)
    vis_rel = float(np.sqrt(vis_err_num / max(vis_err_den, 1e-30)))
    return {"psnr_vs_player": psnr_min, "console_errors": errors, "ms_per_frame": med["step_ms"],
            "ms_pose": med["pose_ms"], "ms_visibility": med["visibility_ms"], "ms_render": med["render_ms"],
            "frames_per_s": 1000.0 / max(med["step_ms"], 1e-9), "raf_fps_playing": raf_fps,
            "visibility_rel_err": vis_rel, "frames": results, "peak_frames": peaks,
            "visibility_rel_err_vs_player": float(np.sqrt(vp_num / max(vis_err_den, 1e-30))),
            "visibility_reference": "onnxruntime" if fp32 is None else
            "onnxruntime, MatMulNBits at accuracy_level 0 (fp32 compute, as onnxruntime-web runs it)",
            "n_vertices": int(m["n_vertices"]), "wasm_threads": wasm_threads, "gl_renderer": gl_renderer,
            "ok": bool(psnr_min >= MIN_PSNR_DB and not errors and vis_rel <= MAX_VIS_REL_ERR),
            "thresholds": {"psnr_db": MIN_PSNR_DB, "visibility_rel_err": MAX_VIS_REL_ERR}}


def _peak_cases(ps: PageSession, player: Any, m: dict[str, Any], site: str | os.PathLike[str],
                cases: list[dict[str, Any]], masker: Any, out_dir: Path | None) -> list[dict[str, Any]]:
    """The page with the sky's peaks on against :func:`prt_torch.web.peaks.page_radiance` (the player's residual
    shading + the peak term, the run's ``peaks.onnx`` in onnxruntime), rendered by the player, one entry per case
    (image PSNR as the other cases)."""
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.peaks import load_peak_lighting
    from prt_torch.player.tonemap import ToneMap
    from prt_torch.rig.material import analytic_brdf, character_material
    from prt_torch.scoring.statistics import image_psnr
    from prt_torch.scoring.strips import abs_diff_image, write_png
    from prt_torch.web.peaks import PeakGraph, page_radiance
    from prt_torch.web.site import ASSETS, PEAKS_MODEL, site_local

    light = m["lights"][0]
    tm = ToneMap(light["peaks"]["tonemap"]["exposure"], light["peaks"]["tonemap"]["white"])
    split = load_peak_lighting(None, player.order, "auto")
    graph_file = Path(site) / ASSETS / PEAKS_MODEL
    graph = PeakGraph(graph_file) if m.get("peaks_model") else None
    material = character_material(player.character)
    whole_lighting = load_lighting(None, player.order)
    saved = player.lighting, player.exposure, player.light_angle
    out = []
    try:
        player.exposure = tm
        for i, case in enumerate(cases):
            local = site_local(player.character, case["clip"], case["frame"])
            player.set_brdf(case["brdf"])
            state, rad, _ = page_radiance(player, local, whole_lighting, split, case["lightAngle"], graph,
                                          analytic_brdf(case["brdf"], material))
            ref = player.render_frame(state, rad)
            mask = masker.mask(state.positions_vx3(0))
            img, _ = ps.frame({**case, "light": "sky", "playing": False, "unshadowed": False, "peaks": True,
                               "tonemap": {"exposure": tm.exposure, "white": tm.white}})
            entry = {**case, "peaks": True, "psnr": float(image_psnr(img, ref, mask)), "mask_pixels": int(mask.sum())}
            if out_dir is not None:
                stem = f"case{i}_{case['clip']}_{case['frame']}_{case['brdf']}_peaks"
                write_png(out_dir / f"{stem}_page.png", img)
                write_png(out_dir / f"{stem}_player.png", ref)
                write_png(out_dir / f"{stem}_diff.png", abs_diff_image(img, ref))
                entry["diff_image"] = str(out_dir / f"{stem}_diff.png")
            out.append(entry)
    finally:
        player.lighting, player.exposure, angle = saved
        player.light_angle = 0.0
        player.rotate_light(angle)
    return out
