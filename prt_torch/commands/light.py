"""``prt light FILE --order N [--lobes K] [--json]``: SH coefficients of an HDR environment map.

Prints the map's SH coefficients (world frame, z up; see :mod:`prt_torch.light.envmap` for the pixel
mappings) and, with ``--lobes K``, a ``K``-lobe ZH fit (:func:`prt_torch.sh.zhfit.fit_zh_lobes`). With
``--json`` one JSON object goes to stdout: ``file``, ``layout``, ``width``, ``height``, ``order``,
``coefficients`` (``n*n`` rows of ``[r, g, b]`` in index order ``l*(l+1)+m``) and, with ``--lobes``,
``lobes`` (``[{"direction": [x, y, z], "coeffs": n rows of [r, g, b]}, ...]``) and ``lobe_rel_error``.

``--sg`` adds the spherical-Gaussian lighting of seed 004 (:func:`prt_torch.sg.lighting.fit_envmap_sg`:
multiscale residual fit on HEALPix grids, peak detection): JSON keys ``sg_lobes``
(``[{"axis": [x, y, z], "sharpness": lambda, "amplitude": [r, g, b]}, ...]``, ``G(v) = amplitude
exp(sharpness (v . axis - 1))``, world frame z up), ``sg_rel_error`` (relative L2 residual after each scale),
``sg_nsides``, ``sg_lobes_per_scale``, ``sg_seconds`` and ``peaks`` (``[{"direction", "solid_angle", "power",
"n_pixels", "lobes"}, ...]``, strongest first); ``--sg-save FILE`` writes the lobes (``.json`` / ``.npz``).
``--sg`` needs the ``sg`` extra (healpy, torch).

``--peaks [K]`` (K in 1..4, default 2) prints the light split of issue 27 instead
(:mod:`prt_torch.sg.split`): the peak lights (direction, elevation / azimuth, angular radius, solid angle,
radiance, share of the map's luminous power) and the residual's power. ``FILE`` may then be ``sky``: the
player's procedural sky, whose sun is the peak by construction (``--sun-radius DEG``, default the real sun's
0.265 deg). With ``--json``: ``file``, ``layout``, ``width``, ``height``, ``order``, ``peaks``
(``[{"direction": [x, y, z], "angular_radius_deg": r, "radiance": [r, g, b]}, ...]``, strongest first: the
schema compare.json carries), ``peak_solid_angle_sr``, ``peak_power`` (RGB each), ``peak_share``,
``residual_power``, ``map_power``, ``energy_rel_error`` (per channel, ``(peaks + residual) / map - 1``) and
``residual_coefficients`` (the residual's SH at ``--order``). A map's split needs the ``sg`` extra.
"""

from __future__ import annotations

import argparse
import json
import sys

HELP = ("Project an HDR environment map (.hdr/.exr/.pfm, lat-long or probe) to SH; optional ZH lobe fit, "
        "--sg spherical-Gaussian fit with peak detection, --peaks the light split (peak lights + residual).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="environment map: .hdr, .exr or .pfm")
    parser.add_argument("--order", type=int, default=3, help="SH order n (bands l < n), 1..16 (default 3)")
    parser.add_argument("--lobes", type=int, default=None, metavar="K", help="also fit K zonal-harmonic lobes")
    parser.add_argument("--layout", default="auto", choices=["auto", "latlong", "probe"],
                        help="pixel layout (auto: 2:1 -> latlong, 1:1 -> probe)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    parser.add_argument("--sg", action="store_true",
                        help="also fit spherical Gaussians (multiscale HEALPix residual fit + peak detection)")
    parser.add_argument("--sg-levels", type=int, default=4, metavar="L",
                        help="last HEALPix scale (nside 2^L, 12*4^L lobes), 0..7 (default 4)")
    parser.add_argument("--sg-threshold", type=float, default=0.02, metavar="E",
                        help="stop once the relative residual is <= E (default 0.02)")
    parser.add_argument("--sg-save", default=None, metavar="FILE", help="write the SG lobes to FILE (.json or .npz)")
    parser.add_argument("--peaks", nargs="?", const="2", default=None, metavar="K",
                        help="print the light split instead: up to K peak lights (default 2, at most 4) + the "
                             "residual; FILE may be 'sky' (the player's procedural sky)")
    parser.add_argument("--sun-radius", type=float, default=None, metavar="DEG",
                        help="with --peaks on 'sky': the sun's angular radius in degrees (default 0.265)")


def run(args: argparse.Namespace) -> int:
    from prt_torch.errors import PrtError
    from prt_torch.light.envmap import load_envmap
    from prt_torch.sh.basis import check_order

    check_order(args.order)
    if args.peaks is not None:
        return _run_peaks(args)
    if args.sun_radius is not None:
        raise PrtError("--sun-radius goes with --peaks")
    if args.lobes is not None and not 1 <= args.lobes <= 16:
        raise PrtError(f"--lobes must be in 1..16, got {args.lobes}")
    from prt_torch.progress import make_console

    err = make_console(stderr=True)
    with err.status(f"projecting {args.file} to order {args.order}", spinner="dots") if not args.json \
            else _null():
        env = load_envmap(args.file, layout=args.layout)
        sh = env.to_sh(args.order)
    lobes = None
    if args.lobes is not None:
        from prt_torch.sh.zhfit import fit_zh_lobes

        with err.status(f"fitting {args.lobes} ZH lobes", spinner="dots") if not args.json else _null():
            lobes = fit_zh_lobes(sh, n_lobes=args.lobes)
    sg = None
    if args.sg:
        sg = _fit_sg(args, env, err)
    h, w = env.shape
    if args.json:
        out: dict[str, object] = {"file": str(args.file), "layout": env.layout, "width": w, "height": h,
                                  "order": args.order, "coefficients": sh.tolist()}
        if lobes is not None:
            out["lobes"] = [{"direction": lobes.dirs[k].tolist(), "coeffs": lobes.coeffs[k].tolist()}
                            for k in range(lobes.n_lobes)]
            out["lobe_rel_error"] = float(lobes.rel_error)
        if sg is not None:
            d = sg.lobes.to_dict()
            out["sg_lobes"] = [{"axis": a, "sharpness": lam, "amplitude": m}
                               for a, lam, m in zip(d["axis"], d["sharpness"], d["amplitude"], strict=True)]
            out["sg_rel_error"] = sg.rel_error_per_scale
            out["sg_nsides"] = sg.nsides
            out["sg_lobes_per_scale"] = sg.lobes_per_scale
            out["sg_peaks_separated"] = sg.peaks_separated
            out["sg_seconds"] = sg.seconds
            out["peaks"] = [p.to_dict() for p in sg.peaks]
        json.dump(out, sys.stdout)
        sys.stdout.write("\n")
        return 0
    _print_tables(args, env.layout, w, h, sh, lobes)
    if sg is not None:
        _print_sg(sg)
    return 0


def _fit_sg(args: argparse.Namespace, env: object, err: object) -> object:
    """Run :func:`prt_torch.sg.lighting.fit_envmap_sg` (one-line error where the ``sg`` extra is missing)."""
    from prt_torch.errors import PrtError

    if not 0 <= args.sg_levels <= 7:
        raise PrtError(f"--sg-levels must be in 0..7, got {args.sg_levels}")
    if not 0 <= args.sg_threshold < 1:
        raise PrtError(f"--sg-threshold must be in [0, 1), got {args.sg_threshold}")
    if args.sg_save is not None and not str(args.sg_save).endswith((".json", ".npz")):
        raise PrtError(f"--sg-save must end in .json or .npz, got {args.sg_save}")
    try:
        import healpy  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise PrtError(f"prt light --sg needs {exc.name}: pip install 'prt-torch[sg]'") from None
    from prt_torch.sg.lighting import fit_envmap_sg

    with err.status(f"fitting spherical Gaussians (HEALPix scales 0..{args.sg_levels})", spinner="dots") \
            if not args.json else _null():  # type: ignore[attr-defined]
        fit = fit_envmap_sg(env, max_level=args.sg_levels, rel_threshold=args.sg_threshold)  # type: ignore[arg-type]
    if args.sg_save is not None:
        fit.lobes.save(args.sg_save)
    return fit


def _print_sg(fit: object) -> None:
    from rich.table import Table

    from prt_torch.progress import make_console

    con = make_console()
    t = Table(title=f"SG lighting: {len(fit.lobes)} lobes, multiscale HEALPix fit in "  # type: ignore[attr-defined]
              f"{fit.seconds['total']:.2f} s (world frame, z up)")  # type: ignore[attr-defined]
    for col in ("scale", "nside", "sharpness", "lobes", "rel. residual"):
        t.add_column(col, justify="right")
    for s, (ns, lam, n, e) in enumerate(zip(fit.nsides, fit.sharpness_per_scale,  # type: ignore[attr-defined]
                                            fit.lobes_per_scale, fit.rel_error_per_scale, strict=True)):  # type: ignore
        t.add_row(str(s), str(ns), f"{lam:.4g}", str(n), f"{e:.4f}")
    con.print(t)
    pt = Table(title=f"{len(fit.peaks)} peaks (threshold + connected components)"  # type: ignore[attr-defined]
               + (": their light above the threshold is in its own lobes" if fit.peaks_separated else ""))  # type: ignore
    for col in ("#", "direction (x, y, z)", "solid angle (sr)", "power (R, G, B)", "pixels", "SGs"):
        pt.add_column(col, justify="right")
    for i, p in enumerate(fit.peaks):  # type: ignore[attr-defined]
        pt.add_row(str(i), ", ".join(f"{x:+.3f}" for x in p.direction), f"{p.solid_angle:.4g}",
                   ", ".join(f"{x:.4g}" for x in p.power), str(p.n_pixels), str(len(p.lobes)))
    con.print(pt)


def _run_peaks(args: argparse.Namespace) -> int:
    """``prt light FILE --peaks [K]``: the light split (:mod:`prt_torch.sg.split`) as a table or JSON."""
    import math

    import numpy as np

    from prt_torch.errors import PrtError
    from prt_torch.sg.split import MAX_PEAKS, SUN_ANGULAR_RADIUS, split_envmap, split_sky

    try:
        k = int(args.peaks)
    except ValueError:
        k = -1
    if not 1 <= k <= MAX_PEAKS:
        raise PrtError(f"--peaks must be an integer in 1..{MAX_PEAKS}, got {args.peaks!r}")
    if args.lobes is not None or args.sg:
        raise PrtError("--peaks prints the light split: run it without --lobes / --sg")
    if str(args.file) == "sky":
        from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION

        r = SUN_ANGULAR_RADIUS if args.sun_radius is None else math.radians(args.sun_radius)
        sun = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
        split = split_sky(sun / np.linalg.norm(sun), DEFAULT_SUN_COLOR, sun_angular_radius=r)
        split.peaks = split.peaks[:k]
        full = None
    else:
        if args.sun_radius is not None:
            raise PrtError("--sun-radius is the procedural sky's ('prt light sky --peaks'); a map's peaks are measured")
        from prt_torch.light.envmap import load_envmap

        full = load_envmap(args.file, layout=args.layout)
        split = split_envmap(full, max_peaks=k)
    env = split.residual
    res_power = split.residual_power()
    if full is None:  # the sky: the lighting is the split itself
        map_power = split.total_power()
    else:
        map_power = full.solid_angles().reshape(-1) @ full.image.reshape(-1, 3).astype(np.float64)
    err_rel = split.total_power() / np.where(map_power > 0, map_power, 1.0) - 1.0
    h, w = env.shape
    if args.json:
        out: dict[str, object] = {"file": str(args.file), "layout": env.layout, "width": w, "height": h,
                                  "order": args.order, **split.to_dict(),
                                  "peak_solid_angle_sr": [p.solid_angle for p in split.peaks],
                                  "peak_power": split.peak_power().tolist(), "peak_share": split.shares().tolist(),
                                  "residual_power": res_power.tolist(), "map_power": map_power.tolist(),
                                  "energy_rel_error": err_rel.tolist(),
                                  "residual_coefficients": env.to_sh(args.order).tolist()}
        json.dump(out, sys.stdout)
        sys.stdout.write("\n")
        return 0
    from rich.table import Table

    from prt_torch.light.envmap import LUMA
    from prt_torch.progress import make_console

    con = make_console()
    con.print(f"{args.file}: {env.layout} {w}x{h}, {len(split.peaks)} peak light(s) of at most {k} "
              "(world frame, z up; azimuth from +x toward +y)", soft_wrap=True)  # a line, whole
    t = Table()
    for col in ("#", "direction (x, y, z)", "elev., azim. (deg)", "radius (deg)", "solid angle (sr)",
                "radiance (R, G, B)", "share"):
        t.add_column(col, justify="right")
    for i, (p, share) in enumerate(zip(split.peaks, split.shares(), strict=True)):
        el, az = p.elevation_azimuth_deg
        t.add_row(str(i), ", ".join(f"{x:+.3f}" for x in p.direction), f"{el:.1f}, {az:.1f}",
                  f"{math.degrees(p.angular_radius):.3f}", f"{p.solid_angle:.3g}",
                  ", ".join(f"{x:.3g}" for x in p.radiance), f"{share:.1%}")
    con.print(t)
    total = float(split.total_power() @ LUMA)
    con.print(f"residual: power (R, G, B) {', '.join(f'{x:.4g}' for x in res_power)}, "
              f"{float(res_power @ LUMA) / total if total > 0 else 0.0:.1%} of the luminous power; "
              f"energy (peaks + residual vs map) {', '.join(f'{x:+.1e}' for x in err_rel)}", soft_wrap=True)
    return 0


class _null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def _print_tables(args: argparse.Namespace, layout: str, w: int, h: int, sh: object, lobes: object) -> None:
    from rich.table import Table

    from prt_torch.progress import make_console

    con = make_console()
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
