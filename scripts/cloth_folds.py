"""docs/cloth_folds.png: the most folded held-out frame of an exported cloth run, learned (the shipped model through
the deformable player) vs the ray-traced truth (the dataset's Embree visibility), both through the player's
shading, camera (player.sequence_view) and ONE tone map fixed from the truth.

    python scripts/cloth_folds.py runs/flag docs/cloth_folds.png [--light-deg 0] [--orbit-deg 0]
"""
from __future__ import annotations

import argparse

import numpy as np

from prt_torch.cloth.player import DeformablePlayer
from prt_torch.rundir import RunDir
from prt_torch.scoring.strips import abs_diff_image, image_strip, write_png


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("out")
    ap.add_argument("--light-deg", type=float, default=0.0, help="rotate the lighting about z (degrees)")
    ap.add_argument("--orbit-deg", type=float, default=0.0, help="orbit the camera from the sequence view (degrees)")
    ap.add_argument("--brdf", default="lambert")
    a = ap.parse_args()
    run = RunDir(a.run)
    ds = run.dataset()
    rows = ds.split_rows("heldout")
    pose = ds.rows(rows, ("pose",))["pose"]
    row = rows[int(np.argmax(np.abs(pose).mean(1)))]  # the most folded held-out frame
    d = ds.rows(np.array([row]), ("positions", "visibility", "pose"))
    p = DeformablePlayer(run.path, brdf=a.brdf, window_size=(600, 800))
    try:
        p.rotate_light(np.radians(a.light_deg))
        body = np.asarray(d["pose"], np.float32)[:, -p.n_body:] if p.n_body else None  # the pose column's body tail
        seq = p.make_sequence(np.asarray(d["positions"], np.float32), body=body, name="heldout")
        p.frame_sequence(seq)
        p.orbit(np.radians(a.orbit_deg))
        state, rad_l = p.compute(seq[:])
        truth = np.asarray(d["visibility"], np.float32)
        rad_t = p.shade(state, visibility=truth)
        unsh = p.shade(state, visibility=np.broadcast_to(p.unshadowed, truth.shape).copy())
        img_t = p.render_frame(state, rad_t)  # fixes the tone map from the truth
        img_l = p.render_frame(state, rad_l)
        img_u = p.render_frame(state, unsh)
        err = float(np.abs(rad_l - rad_t).mean() / np.abs(rad_t).mean())
        kind = f"local_{p.bundle.meta['local']['kind']}" if p.local_graph is not None else \
            f"{p.bundle.meta['model_kind']}, {p.bundle.precision}"  # the shipped local network plays when there is one
        strip = image_strip(
            [img_u, img_t, img_l],
            ["unshadowed (no visibility)", f"ray-traced truth (Embree, {ds.attrs['bake']['n_rays']} rays)",
             f"learned ({kind}), held out"],
            diffs=[None, abs_diff_image(img_u, img_t), abs_diff_image(img_l, img_t)],
            diff_labels=["", "4x |unshadowed - truth|", "4x |learned - truth|"])
        write_png(a.out, strip)
        print(f"row {row}: mean relative radiance error {err:.3f} -> {a.out}")
    finally:
        p.close()


if __name__ == "__main__":
    main()
