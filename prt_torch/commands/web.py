"""``prt web RUN --out DIR [--serve] [--check [--json]]``: the browser player of an exported run."""

from __future__ import annotations

import argparse

HELP = "Write a self-contained browser player (three.js + onnxruntime-web + WebGL2 RPO shading) for a run."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="exported run directory (anything `prt play` plays)")
    parser.add_argument("--out", required=True, help="site directory to write")
    parser.add_argument("--env", action="append", default=[], help="extra HDR env map offered as a lighting "
                                                                   "preset (repeatable)")
    parser.add_argument("--motion", action="append", default=[],
                        help="motion file (.bvh/.glb/.gltf) retargeted onto the character as a clip (repeatable)")
    parser.add_argument("--no-material-rpo", action="store_true",
                        help="do not build the character material's Cook-Torrance RPO")
    parser.add_argument("--serve", action="store_true", help="serve the site on 127.0.0.1 until interrupted")
    parser.add_argument("--port", type=int, default=8000, help="port for --serve (default 8000; 0: any free)")
    parser.add_argument("--check", action="store_true",
                        help="render fixed frames in headless Chromium and compare them with the Python player")
    parser.add_argument("--json", action="store_true", help="with --check: print the result as JSON")
    parser.add_argument("--chromium", default=None, help="Chromium executable for --check (default: found on PATH)")


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError

    V.input_dir(args.run, "run directory")
    for e in args.env:
        V.input_file(e, "--env")
    for mo in args.motion:
        V.input_file(mo, "--motion")
    limits.check_int(args.port, "--port", 0, 65535)
    if args.json and not args.check:
        raise PrtError("--json needs --check")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise PrtError(f"--out: not a directory: {out}")
    from prt_torch.web.site import write_site

    manifest = write_site(args.run, out, env=tuple(args.env), material_rpo=not args.no_material_rpo,
                          motions=tuple(args.motion))
    if not args.json:
        print(f"site written: {out} ({manifest['n_vertices']} vertices, {len(manifest['clips'])} clips, "
              f"BRDFs {[r['name'] for r in manifest['rpos']]}, lights {[x['name'] for x in manifest['lights']]}; "
              f"peaks {_peaks_summary(manifest)}); the player opens on {_start_summary(manifest)}; example.html: two "
              f"characters and three.js objects in one scene (the three.js module)")
    status = 0
    if args.check:
        from prt_torch.web.check import check_site

        result = check_site(out, args.run, chromium=args.chromium, artifacts=out / "check")
        if args.json:
            print(json.dumps(result, indent=2, sort_keys=True))
        else:
            n_frames = len(result["frames"]) + len(result.get("peak_frames", []))
            print(f"psnr_vs_player {result['psnr_vs_player']:.2f} dB (min over {n_frames} frames), "
                  f"console_errors {len(result['console_errors'])}, ms_per_frame {result['ms_per_frame']:.1f}, "
                  f"visibility rel err {result['visibility_rel_err']:.2e}; artifacts in {out / 'check'}")
        status = 0 if result["ok"] else 1
    if args.serve:
        from prt_torch.web.serve import SiteServer

        srv = SiteServer(out, args.port)
        print(f"serving {out} at {srv.url} (127.0.0.1 only; Ctrl-C to stop); the example scene: {srv.url}example.html",
              flush=True)
        try:
            srv.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            srv.close()
    return status


def _start_summary(manifest: dict) -> str:
    """``"wave: held out of training (...); BRDF material"``: what the page opens on, and why that clip."""
    st = manifest.get("start") or {}
    return f"{st.get('clip')}: {st.get('clip_why')}; BRDF {st.get('brdf')}"


def _peaks_summary(manifest: dict) -> str:
    """``"sky 1, uffizi 2 (visibility: learned)"``: the peak lights per lighting, the page's peak-visibility graph."""
    counts = [f"{x['name']} {len(x['peaks']['directions'])}" for x in manifest["lights"] if x.get("peaks")]
    if not counts:
        return "none"
    pm = manifest.get("peaks_model")
    return f"{', '.join(counts)} (visibility: {pm['source'] if pm else 'none, unshadowed'})"
