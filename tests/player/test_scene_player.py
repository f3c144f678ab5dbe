"""ScenePlayer: the Player's public API composed into a scene (floor, several characters, cast shadows).

References: the plain Player (a one-character scene without floor is exactly the player), the torch SHEXP
(``prt_torch.shexp.shexp_visibility``, the floor through onnxruntime matches it), the same characters played
alone (characters far apart do not change each other), and the geometry (the shadow sits under the feet).
"""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.scene.config import scene_from_dict
from tests.scene.fixtures import scene_run  # noqa: F401  (session fixture)


def _scene(**kw):
    return scene_from_dict(kw)


def test_one_character_without_floor_is_the_player(scene_run) -> None:  # noqa: F811
    from prt_torch.player import Player
    from prt_torch.player.scene import ScenePlayer

    sp = ScenePlayer(scene_run, scene=_scene(), clip="wave", window_size=(120, 160))
    p = Player(scene_run, graph="split", window_size=(120, 160))
    try:
        f = sp.compute(2)
        st = p.pose(p.clip_locals("wave", sp.fps)[2:3])
        np.testing.assert_allclose(f.visibility[0], p.visibility(st.features), rtol=1e-6, atol=1e-6)
        # the player's whole radiance: the residual on the SH path + the peak lights' term (issue 27)
        np.testing.assert_allclose(f.radiance[0], p.compute(p.clip_locals("wave", sp.fps)[2:3])[1], rtol=1e-5,
                                   atol=1e-6)
        assert f.ground_radiance is None
    finally:
        sp.close()
        p.close()


def test_far_apart_characters_equal_each_alone(scene_run) -> None:  # noqa: F811
    from prt_torch.player.scene import ScenePlayer

    a = {"clip": "wave", "offset": [0.0, 0.0, 0.0]}
    b = {"clip": "walk", "offset": [60.0, 5.0, 0.0], "yaw_deg": 30.0, "time_offset": 0.3}
    both = ScenePlayer(scene_run, scene=_scene(characters=[a, b]), brdf="lambert", window_size=(120, 160))
    alone = [ScenePlayer(scene_run, scene=_scene(characters=[e]), brdf="lambert", window_size=(120, 160))
             for e in (a, b)]
    try:
        for frame in (0, 3):
            f = both.compute(frame)
            for k, sp in enumerate(alone):
                g = sp.compute(frame)
                np.testing.assert_allclose(f.states[k].positions, g.states[0].positions, atol=1e-5)
                np.testing.assert_allclose(f.visibility[k], g.visibility[0], atol=1e-6)
                np.testing.assert_allclose(f.peak_visibility[k], g.peak_visibility[0], atol=1e-6)
                # lambert: no view dependence, but the peak term's silhouette rule (nothing reflected from below the
                # horizon) depends on the camera, which frames the scene: compare where both cameras see the front
                st, sg = f.states[k], g.states[0]
                front = ((st.normals[0] * st.view_dirs[0]).sum(0) > 0) & ((sg.normals[0] * sg.view_dirs[0]).sum(0) > 0)
                assert front.mean() > 0.3
                np.testing.assert_allclose(f.radiance[k][0, front], g.radiance[0][0, front], rtol=1e-5, atol=1e-6)
    finally:
        for sp in (both, *alone):
            sp.close()


def test_floor_visibility_is_shexp_and_shadow_is_under_the_feet(scene_run) -> None:  # noqa: F811
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.scene.scene import spheres_above
    from prt_torch.shexp import shexp_visibility

    # the SH path alone (peaks 0: the sun's own sharp shadow, tests/scene/test_scene_peaks.py, falls beyond the feet)
    sp = ScenePlayer(scene_run, scene=_scene(ground={"resolution": 24}), clip="wave", window_size=(160, 240), peaks=0)
    try:
        f = sp.compute(1)
        g = sp.ground
        a = sp.actors[0]
        from prt_torch.blockers import pose_spheres
        from prt_torch.rig.skeleton import forward_kinematics

        local = a.locals(np.array([1]), sp.fps)
        skin = forward_kinematics(a.character.parents, local) @ a.character.inverse_bind[None]
        c, r = spheres_above(pose_spheres(a.spheres, skin), a.spheres.radius[None], g.height)
        want = shexp_visibility(g.vertices.copy(), c[0], r[0], sp.order, frames=g.frames().copy()).numpy()
        np.testing.assert_allclose(f.ground_visibility, want, atol=2e-4 * np.abs(want).max())
        # the darkest floor vertex lies within the character's footprint (feet / its shadow), and the floor far
        # away is nearly unshadowed (a 1.8-unit character 2.5 units away covers < 2% of the upper hemisphere)
        pos = f.states[0].positions_vx3(0)
        lum = f.ground_radiance.sum(-1)
        dark = g.vertices[int(np.argmin(lum))]
        lo, hi = pos[:, :2].min(0) - 0.3, pos[:, :2].max(0) + 0.3
        assert np.all(dark[:2] >= lo) and np.all(dark[:2] <= hi)
        far = np.linalg.norm(g.vertices[:, :2] - pos[:, :2].mean(0), axis=1) > 0.45 * g.size
        np.testing.assert_allclose(f.ground_visibility[far, 0], np.sqrt(4 * np.pi), rtol=2e-2)
        assert lum.min() < 0.8 * np.median(lum)
        # in scene, the floor darkens the character's downward-facing vertices (half-space occluder)
        down = f.states[0].normals[0, 2] < -0.7
        alone = sp.primary.visibility(f.states[0].features)
        assert np.abs(f.visibility[0][0, down, 0]).mean() < np.abs(alone[0, down, 0]).mean()
    finally:
        sp.close()


def test_scene_renders_floor_and_shadow(scene_run, tmp_path) -> None:  # noqa: F811
    import imageio.v2 as iio

    from prt_torch.player.scene import ScenePlayer

    sp = ScenePlayer(scene_run, scene=_scene(ground={"resolution": 16}), clip="wave", window_size=(160, 240))
    try:
        res = sp.play(png_dir=tmp_path, max_frames=2)
    finally:
        sp.close()
    assert res["frames"] == 2 and res["compute_fps"] > 0
    img = iio.imread(tmp_path / "frame_00001.png").astype(float)
    bg = np.round(np.array([0.08, 0.08, 0.1]) * 255)
    covered = np.abs(img - bg).max(-1) > 2
    assert covered[-40:].mean() > 0.95  # the floor fills the bottom of the frame


def test_overlapping_characters_are_refused(scene_run) -> None:  # noqa: F811
    from prt_torch.player.scene import ScenePlayer

    sp = ScenePlayer(scene_run, scene=_scene(characters=[{"clip": "wave"}, {"clip": "walk", "offset": [0.2, 0, 0]}]),
                     window_size=(120, 160))
    try:
        with pytest.raises(PrtError, match="overlap") as e:
            sp.compute(0)
        assert "\n" not in str(e.value)
    finally:
        sp.close()


def test_scene_needs_a_clip(scene_run) -> None:  # noqa: F811
    from prt_torch.player.scene import ScenePlayer

    with pytest.raises(PrtError, match="no clip"):
        ScenePlayer(scene_run, scene=_scene(ground={}), window_size=(120, 160))


def test_scene_player_does_not_import_torch(scene_run) -> None:  # noqa: F811
    import subprocess
    import sys

    code = ("import sys; from prt_torch.player.scene import ScenePlayer; from prt_torch.scene.config import "
            "scene_from_dict; sp = ScenePlayer(sys.argv[1], scene=scene_from_dict({'ground': {'resolution': 8}, "
            "'characters': [{'clip': 'wave'}, {'clip': 'walk', 'offset': [2.5, 0, 0]}]})); sp.compute(0); "
            "sp.close(); assert 'torch' not in sys.modules, 'torch imported'")
    r = subprocess.run([sys.executable, "-c", code, str(scene_run)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_scene_camera_is_the_players_orbit_camera(scene_run) -> None:  # noqa: F811
    """``scene.camera`` places the eye exactly where the player's orbit camera is at that azimuth/elevation."""
    from prt_torch.player.player import camera_eye
    from prt_torch.player.scene import ScenePlayer

    cam = {"azimuth_deg": -35.0, "elevation_deg": 26.0}
    sp = ScenePlayer(scene_run, scene=_scene(camera=cam), clip="wave", window_size=(120, 160))
    plain = ScenePlayer(scene_run, scene=_scene(), clip="wave", window_size=(120, 160))
    try:
        want = camera_eye(sp.center, sp.radius, np.radians(-35.0), np.radians(26.0))
        np.testing.assert_allclose(sp.eye, want, rtol=1e-6)
        d = (sp.eye - sp.center) / np.linalg.norm(sp.eye - sp.center)
        assert np.isclose(np.degrees(np.arcsin(d[2])), 26.0, atol=1e-3) and d[0] < 0  # raised, swung toward -x
        assert not np.allclose(plain.eye, sp.eye)
    finally:
        sp.close()
        plain.close()


def test_play_scene_file_with_its_own_clips_needs_no_clip_flag(scene_run, tmp_path, capsys) -> None:  # noqa: F811
    """``prt play RUN --scene FILE`` takes each character's clip from the file; an entry without one (and no
    ``--clip``) is a one-line error, as is ``--clip`` with ``--motion``."""
    import yaml

    from prt_torch.cli import main

    good = tmp_path / "two.yaml"
    good.write_text(yaml.safe_dump({"scene": {"ground": {"resolution": 8}, "characters": [
        {"clip": "wave"}, {"clip": "walk", "offset": [40.0, 0.0, 0.0]}]}}))
    out = tmp_path / "png"
    assert main(["play", str(scene_run), "--scene", str(good), "--png", str(out), "--max-frames", "1"]) == 0
    assert (out / "frame_00000.png").is_file()
    capsys.readouterr()
    bad = tmp_path / "noclip.yaml"
    bad.write_text(yaml.safe_dump({"scene": {"characters": [{"offset": [0.0, 0.0, 0.0]}]}}))
    assert main(["play", str(scene_run), "--scene", str(bad), "--png", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no clip" in err[0], err
    assert main(["play", str(scene_run), "--clip", "wave", "--motion", str(good), "--png", str(out)]) == 2
    assert "not both" in capsys.readouterr().err


def test_scene_plays_a_motion_file_retargeted(scene_run, shared_data, tmp_path, capsys) -> None:  # noqa: F811
    """``prt play RUN --motion FILE.bvh --ground``: the scene's character plays the CMU clip retargeted onto it
    (the same locals as :func:`prt_torch.rig.retarget.retarget_file` gives), on the floor; with ``--clip`` too, a
    one-line error."""
    from prt_torch.cli import main
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.rig.retarget import retarget_file

    bvh = shared_data / "motion" / "01_01.bvh"
    sp = ScenePlayer(scene_run, ground=True, motion=bvh, window_size=(60, 80))
    try:
        want, _ = retarget_file(bvh, sp.primary.character)
        got = sp.actors[0].clip
        assert got.name == want.name and np.asarray(got.local).shape == np.asarray(want.local).shape
        np.testing.assert_allclose(np.asarray(got.local), np.asarray(want.local), atol=1e-9)
        f = sp.compute(5)
        assert f.ground_radiance is not None and np.isfinite(f.radiance[0]).all()
    finally:
        sp.close()
    out = tmp_path / "png"
    assert main(["play", str(scene_run), "--motion", str(bvh), "--ground", "--png", str(out), "--max-frames", "2",
                 "--size", "60x80"]) == 0
    assert (out / "frame_00001.png").is_file()
    capsys.readouterr()
    with pytest.raises(PrtError, match="not both"):
        ScenePlayer(scene_run, ground=True, motion=bvh, clip="wave")


def test_bench_scene_characters_json(scene_run, capsys) -> None:  # noqa: F811
    """``prt bench scene RUN --characters K --json``: the floor + K characters on a grid, ``{"fps", "characters",
    "steps"}`` with the frame's median and its steps (no timing asserted); the grid's characters never meet (the
    scene's separation check runs every frame)."""
    import json

    from prt_torch.cli import main
    from prt_torch.commands.bench_scene import grid_scene

    capsys.readouterr()
    assert main(["bench", "scene", str(scene_run), "--characters", "3", "--frames", "2", "--clip", "wave",
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["characters"] == 3 and out["frames"] == 2 and out["fps"] == pytest.approx(1e3 / out["ms"])
    assert {"pose", "characters", "ground"} <= set(out["steps"]) and out["ground_vertices"] > 0
    from prt_torch.rundir import RunDir

    ch = RunDir(scene_run).character()
    sc = grid_scene(ch, "wave", 5, 3.0)
    offs = np.array([c.offset for c in sc.characters])
    d = np.linalg.norm(offs[:, None, :2] - offs[None, :, :2], axis=-1) + np.eye(5) * 1e9
    assert d.min() >= 1.5 * float(np.ptp(np.asarray(ch.rest_vertices)[:, :2], axis=0).max()) * (1 - 1e-9)
    assert main(["bench", "scene", str(scene_run), "--characters", "0", "--json"]) == 2
