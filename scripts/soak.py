#!/usr/bin/env python3
"""Soak test of the two players (not part of the test suite): is memory flat over a long run?

1. ``play``: the Python player's ``--out`` frame loop (:meth:`prt_torch.player.Player.play`, exactly what
   ``prt play RUN --clip NAME --out video.mp4`` runs: compute, tone map, offscreen VTK render, libx264 writer) over
   ``--frames`` frames (the clip looped), sampling this process's RSS (``/proc/self/status`` VmRSS) by frame count.
2. ``web``: the browser player written by ``prt web`` (:func:`prt_torch.web.site.write_site`), served on 127.0.0.1
   and stepped ``--frames`` times in headless Chromium (``window.prt.setState`` + ``window.prt.render``: posing,
   onnxruntime-web inference, state-texture upload, WebGL draw), sampling the page's JS heap (CDP
   ``Runtime.getHeapUsage`` after ``HeapProfiler.collectGarbage``) and the RSS of the page's Chromium renderer and
   GPU processes.

Each sample is taken after the same number of frames (no timer); the verdict compares the last sample with the one
after ``--warmup`` frames: exit status 1 when the play RSS or the page's JS heap grew by more than ``--tolerance``
(5 %); the renderer's and the GPU process's RSS (wasm memory, GL buffers: outside the JS heap) are printed beside
them, and checked too with ``--check-renderer``.

A RUN directory is any exported run ``prt play`` plays, e.g.::

    prt demo                                   # runs/demo (the built-in character; minutes on 2 cores)
    python3 scripts/soak.py runs/demo

or the test suite's tiny run (tests/export/pipeline.py, ~1 minute), built here with ``--tiny DIR``::

    python3 scripts/soak.py --tiny /tmp/soak      # builds /tmp/soak/tiny_run once, then soaks it

Usage: ``python3 scripts/soak.py RUN [--frames 10000] [--warmup 1000] [--only play|web] [--size 480x640]``.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MB = 1024.0 * 1024.0


def rss_bytes(pid: int | str = "self") -> int:
    """Resident set size of process ``pid`` (``/proc/PID/status`` VmRSS; psutil where there is no /proc)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    import psutil

    return int(psutil.Process(os.getpid() if pid == "self" else int(pid)).memory_info().rss)


def checkpoints(frames: int, warmup: int, count: int = 10) -> list[int]:
    """Frame counts at which to sample: the warm-up, evenly spaced ones after it, and the end."""
    pts = {warmup, frames, *np.linspace(warmup, frames, count + 1).round().astype(int).tolist()}
    return sorted(p for p in pts if 0 < p <= frames)


def soak_play(run: Path, frames: int, warmup: int, size: tuple[int, int], clip: str | None,
              out_dir: Path) -> list[dict[str, float]]:
    """Play ``frames`` frames through :meth:`Player.play` into an MP4; ``[{frames, seconds, rss_mb}]``."""
    from prt_torch.player import Player
    from prt_torch.rig.clip import Clip

    player = Player(run, window_size=size)  # prt play's defaults: fused graph, 2 threads
    try:
        src = player.character.clip(clip or next(iter(player.character.clips)))
        reps = -(-frames // src.num_frames)
        looped = Clip(f"{src.name}-soak", src.fps, np.tile(src.local, (reps, 1, 1, 1))[:frames])
        player.character.clips[looped.name] = looped  # as prt play --motion registers its retargeted clip
        want = checkpoints(frames, warmup)
        samples: list[dict[str, float]] = []
        t0 = time.perf_counter()
        inner = player.compute_stream

        def sampled(locals_: Any, n: int, timer: Any = None) -> Iterator[Any]:
            for i, item in enumerate(inner(locals_, n, timer)):
                if i in want:  # i frames played so far
                    gc.collect()
                    samples.append({"frames": i, "seconds": time.perf_counter() - t0, "rss_mb": rss_bytes() / MB})
                yield item

        player.compute_stream = sampled  # type: ignore[method-assign]
        res = player.play(looped.name, out=out_dir / "soak.mp4", timings=out_dir / "soak_timings.json", progress=False)
        gc.collect()
        samples.append({"frames": res.frames, "seconds": time.perf_counter() - t0, "rss_mb": rss_bytes() / MB})
        return samples
    finally:
        player.close()


def chromium_pids(page: Any) -> dict[str, int]:
    """``{"renderer": pid, "gpu": pid}`` of the Chromium processes of ``page`` (CDP ``SystemInfo.getProcessInfo``):
    the renderer is the largest one (the page's: the others are Chromium's spare and UI renderers); the GPU process
    runs the page's WebGL (SwiftShader, ``--disable-gpu``) and holds its GL buffers and textures."""
    try:
        cdp = page.context.browser.new_browser_cdp_session()
        info = cdp.send("SystemInfo.getProcessInfo")
        cdp.detach()
    except Exception:  # noqa: BLE001 - an older Chromium: report no process RSS
        return {}
    procs = info.get("processInfo", [])
    out = {}
    renderers = [int(p["id"]) for p in procs if p.get("type") == "renderer"]
    if renderers:
        out["renderer"] = max(renderers, key=rss_bytes)
    gpu = [int(p["id"]) for p in procs if p.get("type") == "GPU"]
    if len(gpu) == 1:
        out["gpu"] = gpu[0]
    return out


def soak_web(run: Path, frames: int, warmup: int, site: Path, chromium: str | None,
             batch: int = 250) -> list[dict[str, float]]:
    """Step the page ``frames`` times; ``[{frames, seconds, heap_mb, heap_total_mb, renderer_mb, gpu_mb}]``."""
    from prt_torch.errors import PrtError
    from prt_torch.web.check import served_page
    from prt_torch.web.site import read_manifest, write_site

    if not (site / "assets" / "manifest.json").is_file():
        write_site(run, site)
    m = read_manifest(site)
    clip = m["clips"][0]
    want = checkpoints(frames, warmup)
    step_js = """async ([start, end, nFrames]) => {
        for (let i = start; i < end; i++) {
            await window.prt.setState({ frame: i % nFrames, lightAngle: (i % 360) * Math.PI / 180 });
            await window.prt.render();
        }
        return window.prt.app.stats.steps;
    }"""
    samples: list[dict[str, float]] = []
    with served_page(site, chromium, query="?paused") as ps:
        if not ps.wait_ready(timeout_ms=120000):
            raise PrtError(f"the page failed to start: {ps.page.evaluate('window.prt.error')}")
        cdp = ps.page.context.new_cdp_session(ps.page)
        cdp.send("HeapProfiler.enable")
        pids = chromium_pids(ps.page)
        steps0 = int(ps.page.evaluate("window.prt.app.stats.steps"))
        done = 0
        t0 = time.perf_counter()
        while done < frames:
            nxt = min(frames, next(p for p in want + [frames] if p > done), done + batch)
            steps = ps.page.evaluate(step_js, [done, nxt, int(clip["frames"])])
            done = nxt
            if steps - steps0 != done:
                raise PrtError(f"the page stepped {steps - steps0} times, expected {done}")
            if done in want:
                cdp.send("HeapProfiler.collectGarbage")
                heap = cdp.send("Runtime.getHeapUsage")
                samples.append({"frames": done, "seconds": time.perf_counter() - t0, "heap_mb": heap["usedSize"] / MB,
                                "heap_total_mb": heap["totalSize"] / MB,
                                **{f"{k}_mb": rss_bytes(pids[k]) / MB if k in pids else float("nan")
                                   for k in ("renderer", "gpu")}})
        errors = ps.errors
        cdp.detach()
    if errors:
        raise PrtError(f"the page logged {len(errors)} error(s), the first: {errors[0]}")
    return samples


def growth(samples: list[dict[str, float]], key: str, warmup: int) -> tuple[float, float, float]:
    """``(at warm-up, at the end, relative growth)`` of ``key``."""
    base = next(s for s in samples if s["frames"] >= warmup)[key]
    end = samples[-1][key]
    return base, end, (end - base) / base if base > 0 else float("nan")


def print_table(title: str, samples: list[dict[str, float]], keys: list[str]) -> None:
    print(f"\n{title}")
    print("  " + "  ".join(f"{k:>14}" for k in ["frames", "seconds", *keys]))
    for s in samples:
        print("  " + "  ".join(f"{s[k]:>14.2f}" if k != "frames" else f"{int(s[k]):>14d}"
                               for k in ["frames", "seconds", *keys]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", nargs="?", help="an exported run directory (see the module docstring)")
    ap.add_argument("--tiny", default=None, help="build (once) and soak the tests' tiny run under this folder")
    ap.add_argument("--frames", type=int, default=10000, help="frames played / page steps (default 10000)")
    ap.add_argument("--warmup", type=int, default=1000, help="frames before the baseline sample (default 1000)")
    ap.add_argument("--tolerance", type=float, default=0.05, help="allowed growth after warm-up (default 0.05)")
    ap.add_argument("--only", choices=["play", "web"], default=None, help="soak one player only")
    ap.add_argument("--clip", default=None, help="clip to loop in the play soak (default: the character's first)")
    ap.add_argument("--size", default="480x640", help="play image size HxW (default 480x640, as prt play)")
    ap.add_argument("--site", default=None, help="an existing prt web site of RUN (default: written to a temp dir)")
    ap.add_argument("--chromium", default=None, help="Chromium executable (default: found on PATH)")
    ap.add_argument("--check-renderer", action="store_true", help="fail on the renderer's and GPU process's RSS growth")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO))
    from prt_torch import limits
    from prt_torch.errors import PrtError

    try:
        if (args.run is None) == (args.tiny is None):
            raise PrtError("give a RUN directory or --tiny DIR")
        limits.check_int(args.frames, "--frames", 2, 10_000_000)
        limits.check_int(args.warmup, "--warmup", 1, args.frames - 1)
        size = limits.parse_size(args.size)
        if args.tiny is not None:
            from tests.export.pipeline import build_tiny_run

            Path(args.tiny).mkdir(parents=True, exist_ok=True)
            run = build_tiny_run(Path(args.tiny))
        else:
            run = Path(args.run)
            if not run.is_dir():
                raise PrtError(f"run directory not found: {run}")
        failed: list[str] = []
        rows: list[tuple[str, float, float, float, bool]] = []
        with tempfile.TemporaryDirectory(prefix="prt-soak-") as tmp:
            if args.only in (None, "play"):
                play = soak_play(run, args.frames, args.warmup, size, args.clip, Path(tmp))
                print_table(f"play: {args.frames} frames of Player.play --out", play, ["rss_mb"])
                rows.append(("play RSS (MB)", *growth(play, "rss_mb", args.warmup), True))
                rows.append(("play frames/s", args.frames / play[-1]["seconds"], float("nan"), float("nan"), False))
            if args.only in (None, "web"):
                site = Path(args.site) if args.site else Path(tmp) / "site"
                web = soak_web(run, args.frames, args.warmup, site, args.chromium)
                print_table(f"web: {args.frames} page steps", web,
                            ["heap_mb", "heap_total_mb", "renderer_mb", "gpu_mb"])
                rows.append(("page JS heap used (MB)", *growth(web, "heap_mb", args.warmup), True))
                rows.append(("renderer RSS (MB)", *growth(web, "renderer_mb", args.warmup), args.check_renderer))
                rows.append(("GPU process RSS (MB)", *growth(web, "gpu_mb", args.warmup), args.check_renderer))
                rows.append(("page steps/s", args.frames / web[-1]["seconds"], float("nan"), float("nan"), False))
    except PrtError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"\n{'':24}  {'warm-up':>10}  {'end':>10}  {'growth':>8}  (after {args.warmup} of {args.frames} frames; "
          f"limit {100 * args.tolerance:.0f} %)")
    for name, base, end, g, checked in rows:
        if np.isnan(end):
            print(f"{name:24}  {base:>10.1f}")
            continue
        bad = checked and not g <= args.tolerance
        failed += [name] if bad else []
        print(f"{name:24}  {base:>10.2f}  {end:>10.2f}  {100 * g:>7.2f}%  {'FAIL' if bad else 'ok' if checked else ''}")
    if failed:
        print(f"memory grew after warm-up: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
