"""``prt bench cloth [CONFIG]``: MuJoCo cloth simulation speed at ~2k and ~7.7k cloth vertices, side by side.

For each resolution it builds the scene of the config (or the default flag in a 6 m/s wind, or ``--scene
cape`` on the built-in humanoid walking), simulates ``--frames`` frames after ``--settle`` settle frames and
prints MuJoCo steps per second, output frames per second and the ratio of the two resolutions.
"""

from __future__ import annotations

import argparse
import json

HELP = "Cloth simulation (MuJoCo flex): steps/s and frames/s at ~2k and ~7.7k vertices, side by side."

#: (rows, cols) of the two measured cloths: ~2k and ~7.7k vertices
RESOLUTIONS = {"2k": (64, 32), "7.7k": (124, 62)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", nargs="?", default=None,
                        help="run config with a cloth: section (default: a built-in flag scene)")
    parser.add_argument("--scene", choices=("flag", "cape"), default="flag", help="scene without a config")
    parser.add_argument("--frames", type=int, default=6, help="recorded frames per resolution (default 6)")
    parser.add_argument("--settle", type=int, default=None,
                        help="settle frames (default 2 for the flag, 10 for the cape: its body blends from the bind "
                             "pose to the clip's first frame over half of them)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _config(args: argparse.Namespace) -> object:
    from prt_torch.config import config_from_dict, load_config

    if args.config is not None:
        return load_config(args.config)
    if args.scene == "flag":
        cloth = {"scene": "flag", "train_winds": [{"name": "breeze", "speed": 6.0, "direction_deg": 20.0}]}
        return config_from_dict({"name": "bench_cloth", "character": {}, "cloth": cloth})
    return config_from_dict({"name": "bench_cloth", "character": {"density": 0.5, "train_clips": ["walk"]},
                             "cloth": {"scene": "cape"}})


def run(args: argparse.Namespace) -> int:
    import time

    from rich.table import Table

    from prt_torch import limits
    from prt_torch.cloth.engine import Engine
    from prt_torch.cloth.simulate import simulate_sequence
    from prt_torch.cloth.subject import ClothSubject
    from prt_torch.progress import make_console

    limits.check_int(args.frames, "--frames", 1, 10_000)
    base = _config(args)
    if args.settle is None:
        args.settle = 10 if base.cloth.scene == "cape" else 2
    limits.check_int(args.settle, "--settle", 0, 10_000)
    rows = []
    for label, (r, c) in RESOLUTIONS.items():
        cfg = base.model_copy(deep=True)
        cfg.base_dir = base.base_dir
        cfg.cloth = cfg.cloth.model_copy(update={"rows": r, "cols": c, "settle_frames": args.settle})
        if cfg.cloth.scene == "flag":
            winds = [w.model_copy(update={"frames": args.frames}) for w in cfg.cloth.train_winds[:1]]
            cfg.cloth = cfg.cloth.model_copy(update={"train_winds": winds, "heldout_winds": []})
        subject = ClothSubject.load(cfg)
        name = subject.sequences("train")[0]
        if subject.body is not None:  # the first --frames frames of the first clip
            clip = subject.body_clips[name]
            subject.body_clips[name] = type(clip)(clip.name, clip.fps, clip.local[: args.frames])
        t0 = time.perf_counter()
        engine = Engine(subject)
        build = time.perf_counter() - t0
        res = simulate_sequence(subject, name, engine)
        frames = args.settle + subject.n_frames(name)
        rows.append({"resolution": label, "vertices": len(subject.cloth_rest), "build_s": round(build, 3),
                     "steps_per_s": round(res.steps / res.seconds, 2), "frames_per_s": round(frames / res.seconds, 3),
                     "substeps": cfg.cloth.substeps, "timestep_s": engine.dt})
    ratio = rows[0]["steps_per_s"] / rows[1]["steps_per_s"]
    out = {"scene": base.cloth.scene, "results": rows, "ratio_2k_over_7.7k": round(ratio, 2)}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    t = Table(title=f"cloth simulation ({base.cloth.scene}, MuJoCo flex, 1 thread)")
    for col in ("resolution", "vertices", "build_s", "substeps", "steps_per_s", "frames_per_s"):
        t.add_column(col)
    for row in rows:
        t.add_row(*(str(row[k]) for k in ("resolution", "vertices", "build_s", "substeps", "steps_per_s",
                                           "frames_per_s")))
    make_console().print(t)
    make_console().print(f"2k / 7.7k steps/s: {ratio:.2f}x")
    return 0
