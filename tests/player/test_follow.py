"""The follow camera (prt_torch.player.follow): the track against a brute-force second implementation of the rule,
the character inside the frame of every frame (every posed vertex projected by VTK's own camera, what the renderer
draws with) on root-motion clips where the fixed camera loses it, the track's frame-to-frame change within the
bound the window gives, and a still character framed as the fixed camera frames its pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.player.follow import FOLLOW_SECONDS, clip_follow, follow_track, half_window, posed_bounds
from prt_torch.player.player import CAMERA_AZIMUTH, CAMERA_ELEVATION, camera_eye, camera_target
from prt_torch.rig.builtin import make_character
from prt_torch.rig.clip import Clip
from tests.tolerance import assert_bitwise, gamma, two_path_atol

MOTION = Path(__file__).resolve().parents[3] / "shared" / "data" / "motion" / "94_01.bvh"
WINDOW_HW = (480, 640)
VIEW_ANGLE = 30.0  # MeshRenderer.set_camera's default


@pytest.fixture(scope="module")
def character():
    return make_character(density=0.08, fps=10.0)


def brute_force_track(lo: np.ndarray, hi: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The rule written out frame by frame (loops over explicit windows)."""
    n = len(lo)
    w = max(1, round(FOLLOW_SECONDS * fps))
    win = [range(max(0, t - w), min(n, t + w + 1)) for t in range(n)]
    ulo = np.array([[min(lo[k, a] for k in win[t]) for a in range(3)] for t in range(n)])
    uhi = np.array([[max(hi[k, a] for k in win[t]) for a in range(3)] for t in range(n)])
    c = (ulo + uhi) / 2
    d = np.array([np.sqrt(sum((uhi[t, a] - ulo[t, a]) ** 2 for a in range(3))) for t in range(n)])
    cs = np.array([[sum(c[k, a] for k in win[t]) / len(win[t]) for a in range(3)] for t in range(n)])
    ds = np.array([sum(d[k] for k in win[t]) / len(win[t]) for t in range(n)])
    return cs, ds


def ndc(points: np.ndarray, eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(N, 2)`` normalised device coordinates of ``points (N, 3)`` through a VTK camera set as
    MeshRenderer.set_camera sets it (|x|, |y| <= 1: inside the window)."""
    from vtkmodules.vtkRenderingCore import vtkCamera

    cam = vtkCamera()
    cam.SetPosition(*map(float, eye))
    cam.SetFocalPoint(*map(float, target))
    cam.SetViewUp(0.0, 0.0, 1.0)
    cam.SetViewAngle(VIEW_ANGLE)
    cam.SetClippingRange(1e-3, 1e4)
    m = cam.GetCompositeProjectionTransformMatrix(WINDOW_HW[1] / WINDOW_HW[0], -1.0, 1.0)
    mat = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
    p = np.c_[points, np.ones(len(points))] @ mat.T
    assert (p[:, 3] > 0).all(), "a vertex behind the camera"
    return p[:, :2] / p[:, 3:]


def posed(character, clip: Clip) -> np.ndarray:
    """``(F, V, 3)`` skinned vertices through the character's public posing path."""
    return character.skin_mesh(character.pose(clip))[0].astype(np.float64)


def frame_extent(pos: np.ndarray, track=None, rest=None) -> np.ndarray:
    """``(F,)`` the largest |NDC| coordinate of each frame's vertices (>= 1: the character touches or leaves the
    frame) under the follow track, or the fixed camera of ``rest`` vertices."""
    out = np.empty(len(pos))
    if track is None:
        c, r = camera_target(rest)
        eye = camera_eye(c, r)
    for t in range(len(pos)):
        if track is not None:
            c, _ = track.at(t)
            eye = camera_eye(*track.at(t))
        out[t] = np.abs(ndc(pos[t], eye, c)).max()
    return out


def root_motion_clip(character, fps: float = 10.0) -> Clip:
    """The built-in walk (in place) carried 3 m sideways over its length, then a jump toward the camera (-y) and up:
    root motion the rest pose's camera cannot follow."""
    walk = character.clip("walk")
    loc = np.concatenate([walk.local, walk.local, walk.local])  # 3 loops of the walk
    n = len(loc)
    s = np.linspace(0.0, 1.0, n)
    loc = loc.copy()
    root = int(np.flatnonzero(np.asarray(character.parents) < 0)[0])
    loc[:, root, 0, 3] += 3.0 * s  # sideways
    jump = np.clip((s - 0.6) / 0.4, 0.0, 1.0)
    loc[:, root, 1, 3] -= 1.6 * jump  # toward the camera
    loc[:, root, 2, 3] += 0.5 * np.sin(np.pi * jump)  # and up
    return Clip("walk_across", fps, loc)


def test_track_matches_brute_force():
    rng = np.random.default_rng(0)
    for n, fps in ((1, 10.0), (3, 10.0), (17, 10.0), (40, 30.0), (25, 1.0)):
        lo = rng.normal(size=(n, 3)).cumsum(0)
        hi = lo + rng.uniform(0.1, 2.0, size=(n, 3))
        tr = follow_track(lo, hi, fps)
        cs, ds = brute_force_track(lo, hi, fps)
        assert tr.window == half_window(fps) == max(1, round(0.5 * fps))
        # a few float64 additions of O(10) values: 1e-12 is far above their rounding, far below any rule slip
        np.testing.assert_allclose(tr.center, cs, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr.radius, ds, rtol=0, atol=1e-12)
        flat = np.asarray(tr.flat()).reshape(n, 4)
        assert_bitwise(flat[:, :3], tr.center, why="flat() lists the track's float64 values")
        assert_bitwise(flat[:, 3], tr.radius, why="flat() lists the track's float64 values")


def test_posed_bounds_are_the_posed_vertices_box(character):
    clip = character.clip("squat")
    pos = posed(character, clip)
    lo, hi = posed_bounds(character, clip.local, chunk=7)  # chunks that do not divide the frames
    why = "the same FK, skin matrices and LBS on the same frames (the chunks split frames only)"
    assert_bitwise(lo, pos.min(1), why=why)
    assert_bitwise(hi, pos.max(1), why=why)


def test_still_character_is_framed_as_its_pose(character):
    """One pose held: the follow camera is the fixed camera of that pose (the radius is camera_target's unit)."""
    loc = np.repeat(character.clip("squat").local[5:6], 12, axis=0)
    tr = clip_follow(character, Clip("held", 10.0, loc))
    c, r = camera_target(posed(character, Clip("one", 10.0, loc[:1]))[0])
    # camera_target sums and takes the norm in float32, the track in float64 (a mean of 12 equal values)
    mag = float(np.abs(c).max())
    np.testing.assert_allclose(tr.center, np.broadcast_to(c, tr.center.shape), rtol=0,
                               atol=two_path_atol(2, mag) + 12 * gamma(12, np.float64) * mag)
    np.testing.assert_allclose(tr.radius, r, rtol=gamma(8))
    # camera_eye in float32 on both sides: the centre's and the radius's gaps times the distance, plus its roundings
    np.testing.assert_allclose(camera_eye(*tr.at(3)), camera_eye(c, r, CAMERA_AZIMUTH, CAMERA_ELEVATION), rtol=0,
                               atol=two_path_atol(8, mag + 2 * r))


def check_follows(character, clip: Clip) -> None:
    pos = posed(character, clip)
    tr = clip_follow(character, clip)
    fixed = frame_extent(pos, rest=character.rest_vertices)
    follow = frame_extent(pos, track=tr)
    assert (fixed >= 1.0).sum() > 0.1 * len(pos), f"the fixed camera keeps {clip.name!r} in frame: not a test"
    assert follow.max() < 1.0, f"the follow camera loses the character on frame {int(follow.argmax())}"
    # smoothness: a box mean over n >= W + 1 frames moves by at most span / (W + 1) per frame, span / (2 W + 1)
    # where the window is whole (span: the range of the windowed box's centre / diagonal before the smoothing,
    # itself within the clip's union box)
    lo, hi = posed_bounds(character, clip.local)
    w = tr.window
    from prt_torch.player.follow import window_extrema

    ulo, uhi = window_extrema(lo, hi, w)
    raw_c, raw_d = 0.5 * (ulo + uhi), np.linalg.norm(uhi - ulo, axis=1)
    span_c, span_d = np.ptp(raw_c, axis=0), np.ptp(raw_d)
    dc, dd = np.abs(np.diff(tr.center, axis=0)), np.abs(np.diff(tr.radius))
    tol = 1e-9
    assert (dc <= span_c / (w + 1) + tol).all() and (dd <= span_d / (w + 1) + tol).all()
    whole = slice(w, len(pos) - w - 1)  # steps t -> t+1 with both windows whole
    assert (dc[whole] <= span_c / (2 * w + 1) + tol).all() and (dd[whole] <= span_d / (2 * w + 1) + tol).all()
    # and the track does move: it follows (the root travels several of these steps' worth)
    assert np.ptp(tr.center[:, 0]) > 1.0


def test_follow_keeps_a_root_motion_clip_in_frame(character):
    check_follows(character, root_motion_clip(character))


@pytest.mark.skipif(not MOTION.is_file(), reason=f"{MOTION} absent (../shared data)")
def test_follow_keeps_94_01_in_frame(character):
    from prt_torch.rig.retarget import retarget_file

    motion, _ = retarget_file(MOTION, character)
    check_follows(character, motion)
