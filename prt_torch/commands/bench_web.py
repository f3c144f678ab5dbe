"""``prt bench web RUN``: the browser page's frame in headless Chromium, its step split into posing, inference and
draw, for one character or a crowd of ``K`` drawn in one page (``?characters=K``: one instanced draw, each character
with its own pose, the latent graph run once with batch ``K``).

The site is written into a temporary folder (or ``--site DIR``, an existing ``prt web`` site of the run, is used as
it is), served on 127.0.0.1 and opened paused; every step is one ``window.prt.render()`` with ``syncGpu`` on (the
draw waited for by a one-pixel ``readPixels``), the frame index advanced each step. Reported: the medians over
``--frames`` steps (after two warm-up steps) of the page's own ``performance.now`` split:

* ``posing``: JS posing of every character (pose features, FK, LBS, vertex frames);
* ``inference``: onnxruntime-web (wasm): the latent graph (GPU decode) or, for an export without one, the whole
  visibility graph;
* ``peaks``: the peak lights' visibility graph (wasm), 0 with peaks off (``--no-peaks``) or none in the sky;
* ``draw``: the per-frame upload (positions, frames, peak visibility, z) and the draw, waited for;

``fps`` = 1000 / median step. ``renderer`` is the WebGL renderer string: headless Chromium here has no GPU and
draws with SwiftShader (software GL on the CPU cores, ``software_gl: true``), so ``draw`` is a CPU figure, not a
GPU's. The machine is shared: compare only figures measured side by side.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path
from typing import Any

HELP = "The browser page's frame (posing / wasm inference / draw) in headless Chromium, 1 or K characters."

#: renderer-string fragments of software GL (no GPU behind the figures)
SOFTWARE_GL = ("SwiftShader", "llvmpipe", "softpipe", "Software")
#: page steps run before the timed ones (shader compilation, onnxruntime-web arenas)
WARMUP_STEPS = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/demo", help="exported run (default runs/demo; `prt demo`)")
    parser.add_argument("--characters", type=int, default=1, help="characters drawn in the page (1..64, default 1)")
    parser.add_argument("--frames", type=int, default=12, help="timed steps (default 12)")
    parser.add_argument("--site", default=None, help="an existing `prt web` site of RUN to use (default: written to a "
                                                     "temporary folder)")
    parser.add_argument("--no-peaks", action="store_true", help="the peak lights off (the SH path only)")
    parser.add_argument("--decode", choices=("gpu", "cpu"), default="gpu",
                        help="gpu: the latent graph + the GPU decode (default); cpu: the whole visibility graph in "
                             "wasm, the coefficients uploaded (what an export without latent.onnx plays)")
    parser.add_argument("--chromium", default=None, help="Chromium executable (default: found on PATH)")
    parser.add_argument("--json", action="store_true", help="print the JSON only")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.progress import make_console

    limits.check_int(args.characters, "--characters", 1, 64)
    limits.check_int(args.frames, "--frames", 1, 10_000)
    V.input_dir(args.run, "run directory")
    console = make_console(stderr=True)
    if args.site is not None:
        V.input_dir(args.site, "--site")
        out = bench_site(args.site, args.characters, args.frames, not args.no_peaks, args.chromium, args.decode)
    else:
        from prt_torch.web.site import write_site

        with tempfile.TemporaryDirectory(prefix="prt_bench_web_") as tmp:
            if not args.json:
                console.print(f"writing the site of {args.run} ...")
            write_site(args.run, tmp, material_rpo=False)
            out = bench_site(tmp, args.characters, args.frames, not args.no_peaks, args.chromium, args.decode)
    out["run"] = str(args.run)
    if not args.json:
        s = out["steps"]
        console.print(f"[bold]prt bench web[/] {args.run}: {out['characters']} character(s), {out['n_vertices']} "
                      f"vertices each, decode {out['decode']}, {out['frames']} steps (medians)")
        console.print(f"  {out['fps']:.1f} frames/s = {out['step_ms']:.1f} ms: posing {s['posing']:.2f}, inference "
                      f"{s['inference']:.2f}, peaks {s['peaks']:.2f}, draw {s['draw']:.2f} ms")
        console.print(f"  renderer: {out['renderer']}" + ("  (SOFTWARE GL on the CPU: the draw figure is not a GPU's)"
                                                         if out["software_gl"] else ""))
    print(json.dumps(out))
    return 0


def bench_site(site: str | Path, characters: int, frames: int, peaks: bool = True, chromium: str | None = None,
               decode: str = "gpu") -> dict[str, Any]:
    """The page of ``site`` with ``characters`` characters, ``frames`` timed steps: ``{"characters", "fps",
    "steps": {"posing", "inference", "peaks", "draw"} (median ms), "step_ms", "renderer", "software_gl", "decode",
    ...}`` (module doc)."""
    from prt_torch.errors import PrtError, check
    from prt_torch.web.check import served_page
    from prt_torch.web.site import read_manifest

    m = read_manifest(site)
    clip = m["clips"][0]
    query = f"?paused&characters={characters}" + ("&decode=cpu" if decode == "cpu" else "")
    with served_page(site, chromium, query=query) as ps:
        check(ps.wait_ready(), f"the page failed to start: {ps.page.evaluate('window.prt.error')}")
        ps.page.evaluate("s => window.prt.setState(s)", {"clip": 0, "frame": 0, "playing": False, "paused": True,
                                                         "syncGpu": True, "peaks": peaks, "unshadowed": False})
        steps = []
        for k in range(WARMUP_STEPS + frames):
            ps.page.evaluate("s => window.prt.setState(s)", {"frame": k % clip["frames"]})
            st = ps.page.evaluate("window.prt.render()")
            if k >= WARMUP_STEPS:
                steps.append(st)
        info = ps.page.evaluate("window.prt.info()")
        errors = ps.errors
    if errors:
        raise PrtError(f"the page logged errors: {errors[0]}")

    def med(key: str) -> float:
        return float(statistics.median(s[key] for s in steps))

    step = med("step_ms")
    renderer = str(info["renderer"])
    return {"characters": int(info["characters"]), "fps": 1000.0 / max(step, 1e-9),
            "steps": {"posing": med("pose_ms"), "inference": med("visibility_ms"), "peaks": med("peaks_ms"),
                      "draw": med("render_ms")},
            "step_ms": step, "frames": frames, "renderer": renderer,
            "software_gl": any(s.lower() in renderer.lower() for s in SOFTWARE_GL),
            "decode": str(info["decode"]), "peaks": bool(peaks and any(lt.get("peaks") for lt in m["lights"][:1])),
            "n_vertices": int(m["n_vertices"]), "wasm_threads": int(info["wasmThreads"]),
            "draw_includes": "upload (positions, frames, peak visibility, z) + draw, waited for (1-pixel readPixels)"}
