"""The onnxruntime player on a real tiny run: headless playback (PNG + MP4 + timings), no torch in a
fresh process, shadows where the ray-traced truth has them, batching, and one-line errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import zarr

from prt_torch.errors import PrtError
from prt_torch.player import Player
from prt_torch.player.posing import PoseBatch
from tests.tolerance import assert_bitwise, two_path_atol


def test_fresh_process_plays_headless_without_torch(tiny_run: Path, tmp_path: Path) -> None:
    code = textwrap.dedent(f"""
        import json, sys
        from prt_torch.player import Player
        p = Player({str(tiny_run)!r}, brdf="lambert", window_size=(120, 96))
        res = p.play("wave", png_dir={str(tmp_path / "png")!r}, out={str(tmp_path / "wave.mp4")!r}, max_frames=3,
                     timings={str(tmp_path / "t.json")!r}, progress=False)
        p.close()
        print(json.dumps({{"torch": "torch" in sys.modules, "frames": res.frames}}))
    """)
    repo = Path(__file__).resolve().parents[2]
    r = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out == {"torch": False, "frames": 3}
    import imageio.v2 as iio

    pngs = sorted((tmp_path / "png").glob("frame_*.png"))
    assert len(pngs) == 3
    img = iio.imread(pngs[0])
    assert img.shape == (120, 96, 3) and img.std() > 5  # a character, not a blank image
    reader = iio.get_reader(tmp_path / "wave.mp4")
    assert sum(1 for _ in reader) == 3
    t = json.loads((tmp_path / "t.json").read_text())
    assert t["summary"]["frames"] == 3 and t["summary"]["compute_fps"] > 0
    assert set(t["frames_ms"]) >= {"pose", "compiled", "colors", "render"}  # the default CPU path


def _truth_frame(run: Path, player: Player) -> tuple[PoseBatch, np.ndarray]:
    """The held-out frame with the most ray-traced self-shadowing, as a PoseBatch + its truth visibility."""
    g = zarr.open_group(str(run / "dataset.zarr"), mode="r")
    names = list(g.attrs["clip_names"])
    rows = np.flatnonzero(np.asarray(g["clip_id"][:]) == names.index("wave"))
    vis = np.asarray(g["visibility"].get_orthogonal_selection((rows,)))
    i = rows[int(np.argmin(vis[:, :, 0].mean(axis=1)))]  # least open sky on average
    pos = np.asarray(g["positions"][i:i + 1])
    fr = np.asarray(g["frames"][i:i + 1])
    v = pos.shape[1]
    view = player.eye - pos
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    state = PoseBatch(pos.transpose(0, 2, 1).copy(), fr[:, :, 2].transpose(0, 2, 1).copy(),
                      fr.reshape(1, v, 9).transpose(0, 2, 1).copy(), view.transpose(0, 2, 1).astype(np.float32).copy(),
                      np.asarray(g["pose"][i:i + 1]))
    return state, np.asarray(g["visibility"][i:i + 1])


def test_model_is_darker_where_the_truth_is_shadowed(tiny_run: Path) -> None:
    p = Player(tiny_run, brdf="lambert", window_size=(200, 140))
    try:
        state, truth_vis = _truth_frame(tiny_run, p)
        hemi = np.broadcast_to(p.unshadowed, truth_vis.shape)
        truth = p.shade(state, visibility=truth_vis).sum(-1)[0]
        model = p.shade(state).sum(-1)[0]  # fused graph from the pose
        open_ = p.shade(state, visibility=hemi).sum(-1)[0]
        shadowed = truth < 0.7 * open_
        lit = truth > 0.95 * open_
        assert shadowed.sum() >= 20 and lit.sum() >= 20
        # the model darkens the truly shadowed vertices, and much less the unshadowed ones
        assert model[shadowed].mean() < 0.85 * open_[shadowed].mean()
        drop_shadowed = 1 - model[shadowed].mean() / open_[shadowed].mean()
        drop_lit = 1 - model[lit].mean() / open_[lit].mean()
        assert drop_shadowed > drop_lit + 0.05
        # and the rendered images differ there: pixels of shadowed vertices change more than the rest
        rad_model = p.shade(state)
        rad_open = p.shade(state, visibility=hemi)
        p.exposure = None
        p.colors(rad_open[0])
        img_model = p.render_frame(state, rad_model).astype(float)
        img_open = p.render_frame(state, rad_open).astype(float)
        mask_col = np.where(shadowed[:, None], 1.0, 0.0) * np.ones((1, 3))
        r = p.renderer()
        r.update(state.positions_vx3(0), mask_col)
        mask = r.render()[..., 0] > 128
        other = (~mask) & (img_open.sum(-1) > 30)  # character pixels outside the shadow mask
        diff = np.abs(img_model - img_open).sum(-1)
        assert mask.sum() > 20 and other.sum() > 20
        assert diff[mask].mean() > 1.5 * diff[other].mean()
    finally:
        p.close()


def test_batched_equals_single_and_split_equals_fused(tiny_run: Path) -> None:
    p = Player(tiny_run, brdf="phong")
    try:
        loc = p.clip_locals("wave")[:3]
        _, batched = p.compute(loc)
        singles = np.concatenate([p.compute(loc[i:i + 1])[1] for i in range(3)])
        np.testing.assert_allclose(batched, singles, rtol=1e-5, atol=1e-5 * np.abs(singles).max())
        p.graph = "split"
        _, split = p.compute(loc)
        np.testing.assert_allclose(split, batched, rtol=1e-4, atol=1e-4 * np.abs(batched).max())
        # swapping the BRDF and rotating the light change the picture
        p.set_brdf("lambert")
        _, lam = p.compute(loc[:1])
        p.rotate_light(np.pi / 2)
        _, rot = p.compute(loc[:1])
        assert np.abs(lam - split[:1]).max() > 1e-3 and np.abs(rot - lam).max() > 1e-3
    finally:
        p.close()


def test_errors_are_one_line(tiny_run: Path, tmp_path: Path) -> None:
    p = Player(tiny_run, brdf="phong")
    errors = []
    j = p.character.num_joints
    try:
        for call, msg in [
            (lambda: p.pose(np.zeros((1, j + 1, 4, 4))), "local joint transforms"),
            (lambda: p.pose(np.full((1, j, 4, 4), np.nan)), "NaN"),
            (lambda: p.visibility(np.full((1, p.bundle.n_features), np.nan, np.float32)), "NaN"),
            (lambda: p.visibility(np.zeros((1, p.bundle.n_features + 1), np.float32)), "axis 1"),
            (lambda: p.set_brdf("velvet"), "unknown BRDF"),
            (lambda: p.play("no_such_clip", max_frames=1), "unknown clip"),
        ]:
            with pytest.raises(PrtError, match=msg) as exc:
                call()
            errors.append(str(exc.value))
        # an RPO of another SH order
        from prt_torch.brdf.rpo import build_rpo, builtin_brdf

        build_rpo(builtin_brdf("lambert"), order=3, k=2).save(tmp_path / "o3.npz")
        with pytest.raises(PrtError, match="order 3") as exc:
            p.set_brdf(str(tmp_path / "o3.npz"))
        errors.append(str(exc.value))
    finally:
        p.close()
    # a model exported for another character
    other = tmp_path / "other"
    shutil.copytree(tiny_run, other, ignore=shutil.ignore_patterns("*.mp4", "dataset.zarr"))
    from prt_torch.rig.builtin import make_character

    make_character(density=0.05).save(other / "character.npz")
    with pytest.raises(PrtError, match="not the character") as exc:
        Player(other)
    errors.append(str(exc.value))
    with pytest.raises(PrtError, match="not exported"):
        Player(tmp_path)
    with pytest.raises(PrtError, match="environment map not found"):
        Player(tiny_run, env=tmp_path / "missing.hdr")
    assert all("\n" not in e for e in errors)


def test_prt_play_cli_and_missing_display(tiny_run: Path, tmp_path: Path, monkeypatch) -> None:
    from prt_torch.cli import main

    out = tmp_path / "v.mp4"
    assert main(["play", str(tiny_run), "--clip", "wave", "--brdf", "ggx", "--out", str(out), "--frames", "2",
                 "--size", "96x64"]) == 0
    assert out.is_file() and (tmp_path / "v.timings.json").is_file()
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["play", str(tiny_run), "--clip", "wave"]) == 2  # no display, no --out: a clear error


def test_overlap_mode_equals_fused_and_times_its_steps(tiny_run: Path) -> None:
    """The overlapped path (visibility on a worker thread during the numpy posing) gives the fused graph's
    radiance for single frames and a batch, and records pose / visibility / shading times."""
    from prt_torch.player.timing import FrameTimer
    from prt_torch.rig.vertex_frames import FALLBACK_BELOW

    fused = Player(tiny_run, brdf="phong")
    over = Player(tiny_run, brdf="phong", graph="overlap")
    try:
        loc = fused.clip_locals("wave")[:3]
        n_joints = fused.character.num_joints
        timer = FrameTimer()
        for i in range(3):
            st_f, ref = fused.compute(loc[i:i + 1])
            st_o, got = over.compute(loc[i:i + 1], timer)
            np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())
            assert_bitwise(st_o.features, st_f.features,
                           why='the same numpy operations on the same locals')  # the same numpy ops on the same locals
            # the fused player poses in the graph's cluster-sorted vertex order: the LBS GEMM (J terms) runs on
            # permuted columns, which BLAS may put on other kernel paths; the longest float32 chain after it is
            # about J + 40 roundings of unit-length values, amplified at most 1 / FALLBACK_BELOW by the tangent's
            # normalisation (vertex_frames_soa), so the two frames agree within 2 gamma_(J+40) / FALLBACK_BELOW
            np.testing.assert_allclose(st_o.frames, st_f.frames, rtol=0,
                                       atol=two_path_atol(n_joints + 40, 1 / FALLBACK_BELOW))
        assert {k: len(v) for k, v in timer.steps.items()} == {"pose": 3, "visibility": 3, "shading": 3, "peaks": 3}
        _, batch = over.compute(loc)
        singles = np.concatenate([fused.compute(loc[i:i + 1])[1] for i in range(3)])
        np.testing.assert_allclose(batch, singles, rtol=1e-5, atol=1e-5 * np.abs(singles).max())
        with pytest.raises(PrtError, match="local joint transforms"):
            over.compute(loc[:, :-1])
    finally:
        over.close()
        fused.close()
    with pytest.raises(PrtError, match="unknown graph mode"):
        Player(tiny_run, graph="pipelined")
