"""The follow camera where it ships: ``prt compare``'s images (prt_torch.scoring.images.clip_cameras: every frame
framed as the player frames it; rendered, the character's pixels never touch the image's border on a root-motion
clip whose fixed-camera images they leave), the page's manifest (``camera.follow``: the track as data, 4 floats a
frame) and ``prt play``'s offscreen frames (the player aims at each frame's track entry)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from prt_torch.player.follow import clip_follow
from prt_torch.player.player import camera_eye
from prt_torch.rig.builtin import make_character
from prt_torch.rig.clip import Clip
from prt_torch.scoring.images import Camera, ImageRenderer, clip_cameras, player_camera
from tests.player.test_follow import root_motion_clip
from tests.tolerance import assert_bitwise

HW = (90, 120)


@pytest.fixture(scope="module")
def character():
    return make_character(density=0.08, fps=10.0)


def test_clip_cameras_frame_each_frame_of_its_clip(character):
    whole = root_motion_clip(character)
    part = Clip("part", whole.fps, whole.local[20:45])  # a split's frame range: frames 20..44 of the source
    plans = {"whole": SimpleNamespace(clip=whole, frame_index=np.arange(len(whole.local))),
             "part": SimpleNamespace(clip=part, frame_index=np.arange(20, 45))}
    clips = ["whole", "part", "whole", "part"]
    frame_index = np.array([3, 20, 60, 44])
    cams = clip_cameras(character, plans, clips, frame_index, HW)
    tw, tp = clip_follow(character, whole), clip_follow(character, part)
    for cam, (track, at) in zip(cams, [(tw, 3), (tp, 0), (tw, 60), (tp, 24)], strict=True):
        why = "the same track entry through the same camera_eye"
        assert_bitwise(cam.eye, np.asarray(camera_eye(*track.at(at)), np.float64), why=why)
        assert_bitwise(cam.center, np.asarray(track.at(at)[0], np.float64), why=why)
        assert cam.window_hw == HW
    with pytest.raises(Exception, match="outside its clip"):
        clip_cameras(character, plans, ["part"], np.array([5]), HW)


def border_pixels(mask: np.ndarray) -> int:
    return int(mask[0].sum() + mask[-1].sum() + mask[:, 0].sum() + mask[:, -1].sum())


def coverage(renderer: ImageRenderer, pos: np.ndarray) -> np.ndarray:
    """Pixels the mesh touches at all (white on black, anything above black; the silhouette's blend included)."""
    pl = renderer.renderer.plotter
    pl.set_background((0.0, 0.0, 0.0))
    try:
        img = renderer.render(pos, np.full((len(pos), 3), 255, np.uint8))
    finally:
        pl.set_background(ImageRenderer.BACKGROUND)
    return img.max(-1) > 0


def test_compare_images_keep_the_character_in_frame(character):
    clip = root_motion_clip(character)
    pos = character.skin_mesh(character.pose(clip))[0]
    frames = np.arange(0, len(pos), 4)
    plans = {clip.name: SimpleNamespace(clip=clip, frame_index=np.arange(len(pos)))}
    cams = clip_cameras(character, plans, [clip.name] * len(frames), frames, HW)
    fixed = player_camera(character, HW)
    out_fixed, out_follow, inside = 0, 0, []
    with ImageRenderer(character.rest_vertices, character.faces, fixed) as r:
        for f in frames:
            out_fixed += border_pixels(coverage(r, pos[f])) > 0
        for f, cam in zip(frames, cams, strict=True):
            r.set_camera(cam)
            m = coverage(r, pos[f])
            out_follow += border_pixels(m) > 0
            inside.append(int(m.sum()))
        with pytest.raises(Exception, match="differs from the renderer"):
            r.set_camera(Camera(cams[0].eye, cams[0].center, (10, 10)))
    assert out_fixed >= 3, "the fixed camera keeps this clip in frame: not a test"
    assert out_follow == 0
    assert min(inside) > 0.02 * HW[0] * HW[1]  # and the character is there, not a speck


def test_site_manifest_ships_the_track(tiny_run: Path, tmp_path: Path):
    from prt_torch.web.site import read_manifest, write_site

    write_site(tiny_run, tmp_path / "site", material_rpo=False)
    m = read_manifest(tmp_path / "site")  # what the page reads, from disk
    from prt_torch.rundir import RunDir

    ch = RunDir(tiny_run).character()
    follow = m["camera"]["follow"]
    assert sorted(follow) == sorted(c["name"] for c in m["clips"])
    for c in m["clips"]:
        got = np.asarray(follow[c["name"]], np.float64)
        assert got.shape == (4 * c["frames"],)
        # JSON writes a float64 by its shortest repr, which reads back to the same double
        assert_bitwise(got, np.asarray(clip_follow(ch, c["name"]).flat()), why="a float64 JSON round trip")


def test_player_frames_follow_the_track(tiny_run: Path):
    """``Player.play`` aims each frame at its track entry (the eye the shading and the image use), and puts its
    camera back afterwards."""
    from prt_torch.player.player import Player

    player = Player(tiny_run, brdf="lambert", threads=1, window_size=HW)
    seen = []
    orig = player.compute

    def spy(local, timer=None):
        seen.append((player.center.copy(), player.radius, player.eye.copy()))
        return orig(local, timer)

    player.compute = spy  # type: ignore[method-assign]
    before = (player.center.copy(), player.radius)
    try:
        player.play("wave", progress=False)
        track = player.follow("wave")
        n = len(seen)
        assert n == player.character.clip("wave").num_frames
        for i, (c, r, eye) in enumerate(seen):
            tc, tr = track.at(i)
            assert_bitwise(c, tc, why="the track's entry")
            assert r == tr
            assert_bitwise(eye, camera_eye(tc, tr, player.camera_azimuth, player.camera_elevation),
                           why="camera_eye of the same entry")
        assert_bitwise(player.center, before[0], why="restored")
        assert player.radius == before[1]
        seen.clear()
        player.play("wave", progress=False, camera="fixed")
        assert len(seen) == n
        for c, r, _ in seen:
            assert_bitwise(c, before[0], why="the fixed camera: the rest box's centre, untouched")
            assert r == before[1]
        with pytest.raises(Exception, match="unknown camera"):
            player.play("wave", progress=False, camera="orbit")
    finally:
        player.close()
