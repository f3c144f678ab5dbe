"""``prt light FILE --order N [--lobes K] [--json]``: SH coefficients of an HDR environment map.

Prints the map's SH coefficients (world frame, z up; see :mod:`prt_torch.light.envmap` for the pixel
mappings) and, with ``--lobes K``, a ``K``-lobe ZH fit (:func:`prt_torch.sh.zhfit.fit_zh_lobes`). With
``--json`` one JSON object goes to stdout: ``file``, ``layout``, ``width``, ``height``, ``order``,
``coefficients`` (``n*n`` rows of ``[r, g, b]`` in index order ``l*(l+1)+m``) and, with ``--lobes``,
``lobes`` (``[{"direction": [x, y, z], "coeffs": n rows of [r, g, b]}, ...]``) and ``lobe_rel_error``.
"""

from __future__ import annotations

import argparse
import json
import sys

HELP = "Project an HDR environment map (.hdr/.exr/.pfm, lat-long or probe) to SH; optional ZH lobe fit."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="environment map: .hdr, .exr or .pfm")
    parser.add_argument("--order", type=int, default=3, help="SH order n (bands l < n), 1..16 (default 3)")
    parser.add_argument("--lobes", type=int, default=None, metavar="K", help="also fit K zonal-harmonic lobes")
    parser.add_argument("--layout", default="auto", choices=["auto", "latlong", "probe"],
                        help="pixel layout (auto: 2:1 -> latlong, 1:1 -> probe)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")


def run(args: argparse.Namespace) -> int:
    from prt_torch.errors import PrtError
    from prt_torch.light.envmap import load_envmap
    from prt_torch.sh.basis import check_order

    check_order(args.order)
    if args.lobes is not None and not 1 <= args.lobes <= 16:
        raise PrtError(f"--lobes must be in 1..16, got {args.lobes}")
    from rich.console import Console

    err = Console(stderr=True)
    with err.status(f"projecting {args.file} to order {args.order}", spinner="dots") if not args.json \
            else _null():
        env = load_envmap(args.file, layout=args.layout)
        sh = env.to_sh(args.order)
    lobes = None
    if args.lobes is not None:
        from prt_torch.sh.zhfit import fit_zh_lobes

        with err.status(f"fitting {args.lobes} ZH lobes", spinner="dots") if not args.json else _null():
            lobes = fit_zh_lobes(sh, n_lobes=args.lobes)
    h, w = env.shape
    if args.json:
        out: dict[str, object] = {"file": str(args.file), "layout": env.layout, "width": w, "height": h,
                                  "order": args.order, "coefficients": sh.tolist()}
        if lobes is not None:
            out["lobes"] = [{"direction": lobes.dirs[k].tolist(), "coeffs": lobes.coeffs[k].tolist()}
                            for k in range(lobes.n_lobes)]
            out["lobe_rel_error"] = float(lobes.rel_error)
        json.dump(out, sys.stdout)
        sys.stdout.write("\n")
        return 0
    _print_tables(args, env.layout, w, h, sh, lobes)
    return 0


class _null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def _print_tables(args: argparse.Namespace, layout: str, w: int, h: int, sh: object, lobes: object) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    t = Table(title=f"{args.file}: {layout} {w}x{h}, SH order {args.order} (world frame, z up)")
    for col in ("i", "l", "m", "R", "G", "B"):
        t.add_column(col, justify="right")
    for i, row in enumerate(sh):  # type: ignore[arg-type]
        l = int(i**0.5)
        t.add_row(str(i), str(l), str(i - l * (l + 1)), *(f"{x:.5g}" for x in row))
    con.print(t)
    if lobes is not None:
        lt = Table(title=f"{lobes.n_lobes} ZH lobes, relative error {lobes.rel_error:.4f}")  # type: ignore[attr-defined]
        lt.add_column("k", justify="right")
        lt.add_column("direction (x, y, z)")
        lt.add_column("g_l (R, G, B) per band")
        for k in range(lobes.n_lobes):  # type: ignore[attr-defined]
            d = ", ".join(f"{x:+.3f}" for x in lobes.dirs[k])  # type: ignore[attr-defined]
            g = "; ".join("(" + ", ".join(f"{x:.3g}" for x in band) + ")" for band in lobes.coeffs[k])  # type: ignore
            lt.add_row(str(k), d, g)
        con.print(lt)
