"""``prt bench shade``: the RPO evaluation orders of seed 003 eq. 11 measured side by side.

For ``V`` vertices with random visibility, local lighting and view directions (order ``n``, ``k`` terms,
float32, torch CPU) it times

* ``matrix``  - ``sum_b W_b l . (M_b v)``: ``k`` dense ``C x C`` matrix-vector products per vertex;
* ``product`` - ``sum_b W_b u_b . (l x v)``: one SH product (outer product + GEMM) per RGB channel;
* ``fused``   - ``l . (u~ x v)`` with ``u~ = sum_b W_b u_b``: ONE SH product per vertex for all terms and channels;
* ``fused_gather`` - ``fused`` with the product over the Gaunt non-zeros only (index gathers);
* ``dense``   - the naive triple product: one einsum with the dense ``(C, C, C)`` Gaunt tensor;
* ``lobes``   - rotating 3 ZH lobes into the vertex frames (the per-frame lighting cost),

each the best of ``--repeat`` runs after a warm-up, and prints times and ratios to ``fused``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

from prt_torch.brdf.rpo import DEFAULT_TERMS

HELP = "RPO shading: matrix vs product vs fused evaluation order (and the dense triple product), side by side."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--vertices", type=int, default=20000, help="number of vertices V (default 20000)")
    parser.add_argument("--order", type=int, default=4, help="SH order n (default 4)")
    parser.add_argument("--k", type=int, default=DEFAULT_TERMS, help=f"BRDF terms (default {DEFAULT_TERMS})")
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per method, best kept (default 7)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _best(fn: Callable[[], object], repeat: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch
    from rich.table import Table

    from prt_torch import limits
    from prt_torch.brdf.analytic import Phong
    from prt_torch.brdf.rpo import build_rpo
    from prt_torch.errors import PrtError
    from prt_torch.progress import make_console
    from prt_torch.sh.product import MAX_PRODUCT_ORDER
    from prt_torch.shade.lobes import rotate_lobes_to_frames
    from prt_torch.shade.rpo_shading import RPOTensors, shade_rpo

    limits.check_int(args.vertices, "--vertices", 1, limits.MAX_VERTICES)
    if not 2 <= args.order <= MAX_PRODUCT_ORDER:
        raise PrtError(f"--order must be in 2..{MAX_PRODUCT_ORDER}, got {args.order}")
    limits.check_int(args.k, "--k", 1, limits.MAX_TERMS)
    limits.check_int(args.repeat, "--repeat", 1, limits.MAX_REPEATS)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    c = args.order**2
    # inputs (v, l_local, view, frames) and the largest per-vertex intermediates (a C x C product matrix per
    # colour channel, the k view terms), float32, twice for temporaries
    limits.check_array_memory(args.vertices * (3 * c * c + 3 * args.k * c + 8 * c + 16) * 4 * 2,
                              f"bench shade with --vertices {args.vertices} at --order {args.order}")
    torch.set_num_threads(args.threads)
    err = make_console(stderr=True)
    with err.status("building the RPO", spinner="dots"):
        rpo = build_rpo(Phong(exponent=16.0, kd=0.3, ks=0.7), order=args.order, k=args.k, n_theta=16, n_phi=32)
    t = RPOTensors.from_rpo(rpo, torch.float32)
    n, c, V = args.order, args.order**2, args.vertices
    g = torch.Generator().manual_seed(0)
    v = torch.randn(V, c, generator=g)
    l_local = torch.randn(V, c, 3, generator=g)
    wo = torch.nn.functional.normalize(torch.randn(V, 3, generator=g) + torch.tensor([0.0, 0.0, 2.0]), dim=-1)
    frames = torch.linalg.qr(torch.randn(V, 3, 3, generator=g))[0]
    frames = frames * torch.sign(torch.linalg.det(frames))[:, None, None]
    lobe_dirs = torch.nn.functional.normalize(torch.randn(3, 3, generator=g), dim=-1)
    lobe_coeffs = torch.randn(3, n, 3, generator=g)
    from prt_torch.sh.product import gaunt_tensor

    gamma = gaunt_tensor(n).torch(torch.float32)
    from prt_torch.sh.basis import sh_basis

    def dense() -> torch.Tensor:  # naive: full triple product per channel, then the view factors
        W = sh_basis(wo, n, check=False) @ t.w.T
        u_view = W @ t.u
        return torch.einsum("ijk,vic,vj,vk->vc", gamma, l_local, v, u_view) * t.tint

    fns: dict[str, Callable[[], object]] = {
        "matrix": lambda: shade_rpo(v, l_local, wo, t, "matrix", check=False),
        "product": lambda: shade_rpo(v, l_local, wo, t, "product", check=False),
        "fused": lambda: shade_rpo(v, l_local, wo, t, "fused", check=False),
        "fused_gather": lambda: shade_rpo(v, l_local, wo, t, "fused_gather", check=False),
        "dense": dense,
        "lobes": lambda: rotate_lobes_to_frames(lobe_dirs, lobe_coeffs, frames, check=False),
    }
    with torch.inference_mode():
        ref = shade_rpo(v, l_local, wo, t, "fused", check=False)
        others = ("matrix", "product", "fused_gather", "dense")
        max_diff = {m: float((fns[m]() - ref).abs().max() / ref.abs().max()) for m in others}
        times = {}
        for name, fn in fns.items():
            with err.status(f"timing {name}", spinner="dots"):
                times[name] = _best(fn, args.repeat)
    ratios = {m: times[m] / times["fused"] for m in times}
    result = {"vertices": V, "order": n, "k": args.k, "threads": args.threads, "repeat": args.repeat,
              "seconds": times, "ratio_to_fused": ratios, "max_rel_diff_to_fused": max_diff,
              "mverts_per_s": {m: V / times[m] / 1e6 for m in times}, "torch": torch.__version__,
              "gaunt_nnz": int(gaunt_tensor(n).nnz)}
    if args.json:
        print(json.dumps(result))
        return 0
    table = Table(title=f"RPO shading, V={V}, order {n} (C={c}), k={args.k}, float32, {args.threads} thread(s)")
    for col in ("method", "ms", "M verts/s", "x fused", "max rel diff"):
        table.add_column(col, justify="right")
    for m in times:
        table.add_row(m, f"{times[m] * 1e3:.2f}", f"{V / times[m] / 1e6:.2f}", f"{ratios[m]:.2f}",
                      f"{max_diff[m]:.1e}" if m in max_diff else "-")
    make_console().print(table)
    _ = np  # numpy is imported for the RPO build
    return 0
