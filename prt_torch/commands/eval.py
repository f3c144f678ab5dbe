"""``prt eval RUN``: errors of every trained model against the baked ground truth on the shipping path, with a
report (JSON schema: :mod:`prt_torch.eval.evaluate`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

HELP = "Evaluate a trained run on held-out clips (shipping-path shading, image PSNR, jitter, storage); writes a report."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="trained run directory (runs/NAME), or a run config YAML")
    parser.add_argument("--dataset", default=None, help="baked dataset (default: the run's, else the one recorded at "
                                                        "training time)")
    parser.add_argument("--frames", type=int, default=None,
                        help="cap the frames per split (first frames of each clip; default: every held-out frame)")
    parser.add_argument("--train-frames", type=int, default=48,
                        help="cap the training split (subsampled, contiguous per clip; default 48; 0 = all)")
    parser.add_argument("--image-frames", type=int, default=None,
                        help="frames rendered per split for image PSNR (default: 6 held-out, 3 train; 0 disables)")
    parser.add_argument("--lights", default=None, help="comma-separated lights (sky, uffizi, mondello; default: all "
                                                       "available)")
    parser.add_argument("--no-report", action="store_true", help="skip figures and the shaded image")
    parser.add_argument("--json", action="store_true", help="print the results JSON (models.<kind>.<split>...)")


def run(args: argparse.Namespace) -> int:
    from prt_torch.errors import PrtError
    from prt_torch.eval.evaluate import evaluate_run
    from prt_torch.eval.report import json_summary, write_report, write_results
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    run_dir = Path(args.run)
    from prt_torch import limits
    from prt_torch.commands import _validate as V

    if args.frames is not None:
        limits.check_int(args.frames, "--frames", 2, limits.MAX_FRAMES)
    if args.train_frames == 1:
        raise PrtError(f"--train-frames must be 0 (all) or >= 2, got {args.train_frames}")
    limits.check_int(args.train_frames, "--train-frames", 0, limits.MAX_FRAMES)
    if args.image_frames is not None:
        limits.check_int(args.image_frames, "--image-frames", 0, limits.MAX_FRAMES)
    image_frames = None if args.image_frames is None else {"heldout": args.image_frames, "train": args.image_frames}
    lights = V.names(args.lights, "--lights") if args.lights is not None else None
    if args.dataset is not None:
        V.input_path(args.dataset, "--dataset")
    if run_dir.suffix in (".yaml", ".yml"):
        from prt_torch.config import load_config

        run_dir = Path(load_config(run_dir).out_dir)
    if not run_dir.is_dir():
        raise PrtError(f"run directory not found: {run_dir}")
    run_d = RunDir(run_dir)
    console = make_console(stderr=True)
    ev = evaluate_run(run_d, dataset=args.dataset, max_frames=args.frames, train_frames=args.train_frames or None,
                      lights=lights, image_frames=image_frames, log=console.log, progress=not args.json)
    if args.no_report:
        write_results(ev, run_d)
        index = None
    else:
        with console.status("writing the report"):
            index = write_report(ev, run_d)
    r = ev.results
    if args.json:
        print(json.dumps(json_summary(r), indent=2, sort_keys=True))
        return 0
    console.print(results_table(r, run_dir))
    lf = r.get("lobe_fit", {}).get("heldout", {})
    if lf:
        console.print("lobe fit alone (held-out truth, lobes vs exact, image PSNR dB): " + ", ".join(
            f"{ln}/{bn} {_cell(m['psnr_image'])}" for ln, b in lf.items() for bn, m in b.items()))
    if index is not None:
        console.print(f"report: {index}")
    return 0


#: ``prt eval``'s table: one row per model and split; the image PSNR columns are BRDF (diffuse = lambert, glossy =
#: phong) x lighting (the exact environment, its lobe fit) under the player's light
HEADERS = ("model", "split", "frames", "vis rel err", "jitter", "diffuse exact", "diffuse lobes", "glossy exact",
           "glossy lobes", "glossy lobes rel RMSE")


def _cell(x: float | None, spec: str = ".2f") -> str:
    """A number of the table: ``-`` when absent, ``inf`` for a perfect PSNR."""
    return "-" if x is None else ("inf" if x == float("inf") else format(x, spec))


def results_table(r: dict, run_dir: str | Path) -> Any:
    """The ``rich`` table of an evaluation's results ``r`` (:attr:`prt_torch.eval.evaluate.Evaluation.results`),
    :data:`HEADERS`: readable at 80 columns (:func:`prt_torch.progress.fitted_table`)."""
    from prt_torch.progress import fitted_table

    frames = ", ".join(f"{s}: {n} frames{' (subsampled)' if s == 'train' and r['train_subsampled'] else ''}, "
                       f"{r['image_frames'].get(s, 0)} rendered" for s, n in r["frames"].items())
    rows = []
    for kind, splits in r["models"].items():
        for split, m in splits.items():
            sky = m["shading"].get(r["player_light"]) or next(iter(m["shading"].values()))
            cells = [_cell(sky.get(b, {}).get(p, {}).get("psnr_image")) for b in ("lambert", "phong")
                     for p in ("exact", "lobes")]
            rows.append([kind, split, str(m["frames"]), _cell(m["vis_rel_err"], ".4f"), _cell(m["jitter"], ".4f"),
                         *cells, _cell(sky.get("phong", {}).get("lobes", {}).get("radiance_rel_rmse"), ".4f")])
    return fitted_table(HEADERS, rows, left=2, title=f"prt eval {run_dir} ({frames}); image PSNR dB (character "
                                                     "pixels), player's sky, exact / lobes lighting")
