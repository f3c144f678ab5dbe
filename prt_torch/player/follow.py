"""The follow camera: where the player's orbit camera looks, per frame of a clip (the one rule).

A clip with root motion (a walk across the room, a jump toward the camera) leaves the fixed camera's frame, which
orbits the REST pose's box. The follow camera frames the POSED character instead, over a window of frames and
smoothly, so that it neither loses the character nor jitters with every step:

* per frame ``t`` the posed vertices' box ``b_lo[t], b_hi[t]`` (:func:`posed_bounds`);
* half-window ``W = max(1, round(FOLLOW_SECONDS * fps))`` (:func:`half_window`);
* the windowed union ``lo[t] = min b_lo[t-W .. t+W]``, ``hi[t] = max b_hi[t-W .. t+W]`` (the window clipped to the
  clip);
* centre ``c = (lo + hi) / 2`` and size ``d = |hi - lo|``, each then smoothed by a box mean over the same (clipped)
  window (:func:`follow_track`);
* the eye is :func:`prt_torch.player.player.camera_eye` ``(c[t], d[t], azimuth, elevation)``.

``d`` is the box's DIAGONAL, the unit of the player's camera "radius" (:func:`~prt_torch.player.player.camera_target`
returns the rest box's diagonal, and :func:`~prt_torch.player.player.camera_eye` puts the eye
``CAMERA_DISTANCE`` of them away): for a character that stands still the follow camera IS the fixed camera of its
pose. ``d / 2`` is the radius of the box's bounding sphere.

Why the character stays inside the sphere ``(c[t], d[t] / 2)`` of every frame: a vertex ``p`` of frame ``t`` lies in
the union box of every frame ``t'`` whose window holds ``t`` - exactly the frames the smoothing averages at ``t`` -
so ``|p - c[t']| <= d[t'] / 2`` for each of them, and by the triangle inequality ``|p - mean c| <= mean d / 2``.
The sphere's angular radius from the eye is ``asin(1 / (2 CAMERA_DISTANCE))`` (15.3 degrees at 1.9) against the
window's 15 degree half-height, so a vertex could only leave the frame at the very top or bottom of the sphere,
which a box's corners rarely put a vertex near (tests project every vertex).

Smoothness: the box mean of a window of ``n >= W + 1`` frames changes by at most ``span / (W + 1)`` from one frame
to the next (``span``: the range of the unsmoothed ``c`` or ``d`` over the clip; ``span / (2 W + 1)`` where the
window is whole).

The player (:meth:`prt_torch.player.player.Player.play`), the page (``camera.follow`` of the site's manifest, the
track as data) and ``prt compare``'s images (:func:`prt_torch.scoring.images.player_camera`) use this one track.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape

#: the follow window's half-width in seconds
FOLLOW_SECONDS = 0.5
#: frames posed at once when measuring a clip's boxes (bounded memory: frames x vertices x joints)
POSE_CHUNK = 32


def half_window(fps: float) -> int:
    """``W = max(1, round(FOLLOW_SECONDS * fps))`` frames: the follow window is ``[t - W, t + W]``."""
    check(bool(np.isfinite(fps)) and fps > 0, f"follow camera: the clip's rate must be > 0 frames/s, got {fps}")
    return max(1, int(round(FOLLOW_SECONDS * float(fps))))


def _windows(n: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """``(start, stop)`` (each ``(n,)``) of the windows ``[t - w, t + w]`` clipped to ``0 .. n-1`` (stop exclusive)."""
    t = np.arange(n)
    return np.maximum(t - w, 0), np.minimum(t + w + 1, n)


def window_extrema(lo: np.ndarray, hi: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """The windowed union of boxes ``lo, hi (T, 3)``: ``min lo`` and ``max hi`` over ``[t - w, t + w]`` clipped to the
    clip, each ``(T, 3)`` (a sliding minimum / maximum; edge padding does not change an extremum)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    return (minimum_filter1d(lo, size=2 * w + 1, axis=0, mode="nearest"),
            maximum_filter1d(hi, size=2 * w + 1, axis=0, mode="nearest"))


def window_mean(x: np.ndarray, w: int) -> np.ndarray:
    """The box mean of ``x (T, ...)`` over ``[t - w, t + w]`` clipped to the clip (each window divided by its own
    count), float64, same shape."""
    x = np.asarray(x, dtype=np.float64)
    start, stop = _windows(len(x), w)
    csum = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, axis=0)])
    count = (stop - start).reshape(-1, *([1] * (x.ndim - 1)))
    return (csum[stop] - csum[start]) / count


@dataclass(frozen=True)
class FollowTrack:
    """A clip's follow camera: ``center (T, 3)`` and ``radius (T,)`` float64 per frame (``radius``: the player's
    camera unit, a box diagonal; module docstring), the clip's ``fps`` and the half-window ``window`` in frames."""

    center: np.ndarray
    radius: np.ndarray
    fps: float
    window: int

    def __len__(self) -> int:
        return int(len(self.radius))

    def at(self, frame: int) -> tuple[np.ndarray, float]:
        """``(center (3,) float32, radius)`` of ``frame`` (clamped to the clip): the eye is
        :func:`prt_torch.player.player.camera_eye` ``(*track.at(frame), azimuth, elevation)``."""
        i = min(max(int(frame), 0), len(self) - 1)
        return self.center[i].astype(np.float32), float(self.radius[i])

    def flat(self) -> list[float]:
        """The track as data (the page's ``camera.follow[clip]``): ``4 T`` floats ``cx, cy, cz, radius`` per frame."""
        return np.concatenate([self.center, self.radius[:, None]], axis=1).astype(float).ravel().tolist()


def follow_track(lo: np.ndarray, hi: np.ndarray, fps: float) -> FollowTrack:
    """The follow camera (module docstring) of a clip whose frames' boxes are ``lo, hi (T, 3)`` at ``fps``."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    check_shape(lo, "T 3", name="follow camera box minima")
    check_shape(hi, (lo.shape[0], 3), name="follow camera box maxima")
    check(lo.shape[0] > 0, "follow camera: a clip of no frames")
    check(bool(np.isfinite(lo).all() and np.isfinite(hi).all()), "follow camera: posed boxes contain NaN or inf")
    check(bool((hi >= lo).all()), "follow camera: a box's maximum is below its minimum")
    w = half_window(fps)
    ulo, uhi = window_extrema(lo, hi, w)
    center = window_mean(0.5 * (ulo + uhi), w)
    radius = window_mean(np.linalg.norm(uhi - ulo, axis=1), w)
    return FollowTrack(center, radius, float(fps), w)


def posed_bounds(character: Any, local: np.ndarray, chunk: int = POSE_CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` each ``(F, 3)`` float64: the box of the character's skinned vertices in each of the frames
    ``local (F, J, 4, 4)`` (the library's FK and LBS, :meth:`prt_torch.rig.character.Character.skin_mesh`; ``chunk``
    frames at a time)."""
    from prt_torch.exact import small_matmul
    from prt_torch.rig.skeleton import forward_kinematics

    local = np.asarray(local, dtype=np.float64)
    check_shape(local, ("F", character.num_joints, 4, 4), name="follow camera: local transforms")
    n = local.shape[0]
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    for s in range(0, n, chunk):
        world = forward_kinematics(character.parents, local[s:s + chunk])
        pos, _ = character.skin_mesh(small_matmul(world, character.inverse_bind[None]))
        lo[s:s + chunk], hi[s:s + chunk] = pos.min(axis=1), pos.max(axis=1)
    return lo, hi


def clip_follow(character: Any, clip: Any, fps: float | None = None) -> FollowTrack:
    """The follow camera of ``clip`` (a name or a :class:`~prt_torch.rig.clip.Clip` of ``character``), resampled at
    ``fps`` when given (as the player plays it)."""
    c = character.clip(clip)
    if fps is not None and fps != c.fps:
        c = c.resample(fps)
    lo, hi = posed_bounds(character, c.local)
    return follow_track(lo, hi, float(c.fps))
