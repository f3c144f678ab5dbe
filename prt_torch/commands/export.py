"""``prt export RUN``: ONNX graphs (visibility, shading, fused) + RPO files + export.json, checked
against torch on held-out poses."""

from __future__ import annotations

import argparse

from prt_torch.brdf.rpo import DEFAULT_TERMS

HELP = "Export a trained run to ONNX (visibility, RPO shading, fused graphs) with a parity check vs torch."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run directory (runs/NAME) or a config YAML whose run is exported")
    parser.add_argument("--kind", default=None, choices=["linear", "quadratic", "mlp"],
                        help="model kind (default: the run's default model)")
    parser.add_argument("--brdfs", default=None, help="comma-separated named BRDFs to export as RPOs")
    parser.add_argument("--terms", type=int, default=DEFAULT_TERMS,
                        help=f"BRDF terms k of the shading graph (default {DEFAULT_TERMS}; 1..64)")
    parser.add_argument("--opset", type=int, default=17, help="ONNX opset (17..20)")
    parser.add_argument("--exporter", default="torchscript", choices=["torchscript", "dynamo"])
    parser.add_argument("--force", action="store_true", help="re-export even if up to date")
    parser.add_argument("--precision", default=None, choices=["fp32", "fp16", "int8"],
                        help="weight precision of the model's output bases (default int8: prt compare rows "
                             "learned_<kind>_fp32/_fp16 measure the cost)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from prt_torch import limits
    from prt_torch.brdf.rpo import CATALOGUE
    from prt_torch.commands import _validate as V
    from prt_torch.export.run import DEFAULT_BRDFS, export_run
    from prt_torch.progress import make_console

    limits.check_int(args.terms, "--terms", 1, limits.MAX_TERMS)
    limits.check_int(args.opset, "--opset", limits.MIN_OPSET, limits.MAX_OPSET)
    brdfs = (tuple(V.names(args.brdfs, "--brdfs", tuple(CATALOGUE), what="BRDF")) if args.brdfs is not None
             else DEFAULT_BRDFS)
    console = make_console(stderr=True)
    run_dir = Path(args.run)
    if run_dir.suffix in (".yaml", ".yml"):
        from prt_torch.config import load_config

        run_dir = load_config(run_dir).out_dir
    V.input_dir(run_dir, "run directory")
    with console.status(f"exporting {run_dir} ..."):
        meta = export_run(run_dir, kind=args.kind, brdfs=brdfs, n_terms=args.terms, opset=args.opset,
                          exporter=args.exporter, force=args.force, console=console,
                          **({"precision": args.precision} if args.precision else {}))
    par = ", ".join(f"{k} {v['rel_error']:.1e}" for k, v in meta["parity"].items())
    console.print(f"exported {run_dir}: V={meta['n_vertices']} order={meta['sh_order']} "
                  f"BRDFs={','.join(meta['brdfs'])}; parity vs torch (rel.): {par}")
    return 0
