"""``prt bench sglight``: spherical-Gaussian lighting fit time per environment map (seed 004 sec. 6), side by side.

For each map (default: the HDR maps in ``../shared/data/envmaps``, else a synthetic 512 x 1024 sky with a sun)
it times, best of ``--repeat`` runs after a warm-up, single BLAS thread:

* ``sh4``    - the project's SH projection of the map to order 4 (``EnvMap.to_sh``: the SH lighting path);
* ``peaks``  - peak detection alone (:func:`prt_torch.sg.lighting.detect_peaks`);
* ``sg L``   - the whole multiscale residual HEALPix fit up to scale ``L`` (peaks detected and separated,
  every scale run: ``rel_threshold = 0``), for each ``L`` in ``--levels``,

and prints milliseconds, the ratio to ``sh4``, fits per second (seed 004 fits every video frame), the number of
lobes and the final relative residual.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

HELP = "SG lighting: multiscale HEALPix fit and peak detection time per env map vs the SH projection."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("maps", nargs="*", metavar="MAP", help="environment maps (default: ../shared/data/envmaps)")
    parser.add_argument("--levels", type=int, nargs="+", default=[3, 4], metavar="L",
                        help="last HEALPix scales to time (default 3 4)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per method, best kept (default 3)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _best(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    out = fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _default_maps() -> list[Path]:
    d = Path(__file__).resolve().parents[3] / "shared" / "data" / "envmaps"
    return sorted(p for p in d.glob("*") if p.suffix.lower() in (".hdr", ".exr", ".pfm")) if d.is_dir() else []


def _synthetic() -> object:
    import numpy as np

    from prt_torch.light.envmap import EnvMap, latlong_directions

    d = latlong_directions(512, 1024)
    sun = np.array([0.5, 0.6, 0.62])
    sun /= np.linalg.norm(sun)
    img = 0.3 + 0.7 * np.clip(d[..., 2:3], 0, 1) * np.array([0.6, 0.8, 1.0])
    img = np.where((d @ sun > np.cos(np.radians(0.5)))[..., None], 5e4, img)
    return EnvMap(img.astype(np.float32), "latlong", source="synthetic sky + sun")


def run(args: argparse.Namespace) -> int:
    from rich.table import Table
    from threadpoolctl import threadpool_limits

    from prt_torch.errors import PrtError
    from prt_torch.light.envmap import load_envmap
    from prt_torch.progress import make_console
    from prt_torch.sg.lighting import MAX_LEVEL, detect_peaks, fit_envmap_sg, require_healpy

    require_healpy()
    if args.repeat < 1:
        raise PrtError(f"--repeat must be >= 1, got {args.repeat}")
    for lv in args.levels:
        if not 0 <= lv <= MAX_LEVEL:
            raise PrtError(f"--levels must be in 0..{MAX_LEVEL}, got {lv}")
    envs = [load_envmap(p) for p in args.maps] if args.maps else [load_envmap(p) for p in _default_maps()]
    if not envs:
        envs = [_synthetic()]
    rows = []
    with threadpool_limits(1):
        for env in envs:
            name = Path(env.source).name or env.source
            h, w = env.shape
            t_sh, _ = _best(lambda env=env: env.to_sh(4), args.repeat)
            t_pk, pk = _best(lambda env=env: detect_peaks(env), args.repeat)
            rows.append({"map": name, "size": f"{w}x{h}", "method": "sh4", "ms": 1e3 * t_sh})
            rows.append({"map": name, "size": f"{w}x{h}", "method": "peaks", "ms": 1e3 * t_pk,
                         "peaks": len(pk)})  # type: ignore[arg-type]
            for lv in args.levels:
                t, fit = _best(lambda env=env, lv=lv: fit_envmap_sg(env, max_level=lv, rel_threshold=0.0),
                               args.repeat)
                rows.append({"map": name, "size": f"{w}x{h}", "method": f"sg {lv}", "ms": 1e3 * t,
                             "lobes": len(fit.lobes), "rel_error": fit.rel_error_per_scale[-1],  # type: ignore
                             "rel_error_per_scale": fit.rel_error_per_scale,  # type: ignore[attr-defined]
                             "peaks": len(fit.peaks)})  # type: ignore[attr-defined]
            ref = rows[-2 - len(args.levels)]["ms"]
            for r in rows[-2 - len(args.levels):]:
                r["ratio_to_sh4"] = r["ms"] / ref
                r["per_second"] = 1e3 / r["ms"]
    if args.json:
        print(json.dumps({"rows": rows}))
        return 0
    t = Table(title=f"SG lighting fit time per map (best of {args.repeat}, 1 BLAS thread)")
    for col in ("map", "size", "method", "ms", "x sh4", "per s", "lobes", "peaks", "rel. residual"):
        t.add_column(col, justify="right")
    for r in rows:
        t.add_row(r["map"], r["size"], r["method"], f"{r['ms']:.1f}", f"{r['ratio_to_sh4']:.1f}",
                  f"{r['per_second']:.2f}", str(r.get("lobes", "")), str(r.get("peaks", "")),
                  f"{r['rel_error']:.4f}" if "rel_error" in r else "")
    make_console().print(t)
    return 0
