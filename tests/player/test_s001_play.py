"""``prt play --renderer s001|posespace`` (:mod:`prt_torch.s001.renderer`) on the tiny seed-001 run.

Reference: the frame posed by the bake's code (``Character.pose`` + ``skin_mesh`` + ``rig.vertex_frames``, as
``prt compare`` poses clips), the interpolated matrices ``S001Player.transfer`` shaded by
:func:`prt_torch.s001.shading.shade_matrix` (eq. 5 per vertex, not the player's eq. 9 order) with the
procedural sky's SH and the catalogue BRDF's matrix factors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from tests.torchfree import run_cli_without_torch


@pytest.mark.parametrize("scheme", ["s001", "posespace"])
def test_play_radiance_is_shade_matrix_of_interpolated_matrices(s001_run: tuple[Path, Path], scheme: str) -> None:
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.player.lighting import load_lighting
    from prt_torch.rig.vertex_frames import vertex_frames
    from prt_torch.rundir import RunDir
    from prt_torch.s001.brdf_matrix import brdf_matrix, factor
    from prt_torch.s001.renderer import S001RunPlayer
    from prt_torch.s001.shading import shade_matrix

    _, run = s001_run
    p = S001RunPlayer(run, brdf="phong", scheme=scheme, window_size=(64, 64))
    state, rad = p.compute(p.clip_locals("wave")[:1])
    got = rad[0].astype(np.float64)

    rd = RunDir(run)
    ch, ds = rd.character(), rd.dataset()
    poses = ch.pose("wave")
    skin = poses.skin[:1]
    pos, nrm = ch.skin_mesh(skin)
    frames = np.asarray(vertex_frames(nrm, skin, ds.cluster, ds.cluster_axis, ds.cluster_bone), np.float64)[0]
    feats = np.asarray(poses.features[0], np.float64)
    np.testing.assert_allclose(state.features[0], feats, atol=1e-4)  # same pose as the bake's code
    t = p.s001.transfer(feats, frames).astype(np.float64)  # (V, C, C) interpolated, store convention
    order = p.order
    b = builtin_brdf("phong")
    h, g = factor(brdf_matrix(b, order), 4)
    light = np.asarray(load_lighting(None, order).sh, np.float64)
    view = p.eye[None] - pos[0].astype(np.float64)
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    want = shade_matrix(t, light, frames, view, h, g, np.asarray(getattr(b, "tint", np.ones(3))))
    err = np.linalg.norm(got - want) / np.linalg.norm(want)
    assert err < 2e-3, err
    assert np.ptp(want.mean(1)) > 0.1 * np.abs(want).mean()  # a shaded (not constant) frame
    p.close()


def test_play_command_writes_frames_without_torch(s001_run: tuple[Path, Path], tmp_path: Path) -> None:
    _, run = s001_run
    png, timings = tmp_path / "png", tmp_path / "t.json"
    run_cli_without_torch(["play", str(run), "--clip", "wave", "--renderer", "s001", "--max-frames", "2",
                           "--size", "96x128", "--png", str(png), "--timings", str(timings), "--light-angle", "30"])
    import imageio.v2 as iio

    frames = sorted(png.glob("frame_*.png"))
    assert len(frames) == 2
    img = np.asarray(iio.imread(frames[0]))
    assert img.shape[:2] == (96, 128) and img.std() > 5  # the character is drawn
    t = json.loads(timings.read_text())
    assert t["graph"] == "s001" and t["summary"]["frames"] == 2 and t["sh_order"] == 3


def test_play_s001_without_s001_npz_is_one_line_error(s001_run: tuple[Path, Path], tmp_path: Path) -> None:
    from prt_torch.cli import main
    from prt_torch.s001.renderer import S001RunPlayer

    empty = tmp_path / "run"
    empty.mkdir()
    with pytest.raises(PrtError, match="s001.npz missing") as exc:
        S001RunPlayer(empty)
    assert "\n" not in str(exc.value)
    _, run = s001_run
    with pytest.raises(PrtError, match="catalogue BRDFs"):
        S001RunPlayer(run, brdf="velvet")
    assert main(["play", str(empty), "--clip", "wave", "--renderer", "posespace", "--png", str(tmp_path / "p")]) == 2
