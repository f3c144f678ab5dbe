"""Images on the shipping path: the player's camera, renderer and tone map.

The player's camera (:func:`player_camera`: :attr:`prt_torch.player.Player.eye` rule and its window size; the
frames of a clip at the player's follow camera, :func:`clip_cameras`: :mod:`prt_torch.player.follow`, the image-PSNR
camera contract),
its :class:`~prt_torch.player.render.MeshRenderer` and its tone map
(:func:`~prt_torch.player.tonemap.auto_tonemap`), fixed ONCE per frame from the truth radiance and applied
to every prediction of that frame (:meth:`ImageRenderer.frame_images`). The mask holds the pixels *fully*
covered by the mesh (a render with white vertex colours on a black background reads 255 in every channel;
anti-aliased silhouette pixels, which mix in the background, are excluded); the errors over it are
:mod:`prt_torch.scoring.statistics`'.

The character's base colour is the player's (:class:`prt_torch.player.material.SurfaceAlbedo`, ``albedo=``): the
tone map is fixed from the truth's SURFACE radiance (radiance times the per-vertex base colour, what
:meth:`prt_torch.player.Player.colors` fixes it from), vertex colours are the tone-mapped surface radiance, and a
textured character's interior pixels are shaded per pixel from the linear radiance and the texture, as
:meth:`prt_torch.player.Player.render_frame` does. Without ``albedo`` (or a white one) images are the radiance's own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import check
from prt_torch.scoring.statistics import image_sse

if TYPE_CHECKING:
    from prt_torch.player.material import SurfaceAlbedo

#: the player's default window ``(H, W)`` (``Player(window_size=...)``)
WINDOW_HW = (480, 640)


@dataclass(frozen=True)
class Camera:
    """The player's camera: ``eye`` and ``center (3,)`` world, window ``(H, W)`` pixels."""

    eye: np.ndarray
    center: np.ndarray
    window_hw: tuple[int, int] = WINDOW_HW


def clip_cameras(character: Any, plans: Mapping[str, Any], clips: list[str], frame_index: np.ndarray,
                 window_hw: tuple[int, int] = WINDOW_HW) -> list[Camera]:
    """Per frame ``f`` the player's follow camera (:func:`prt_torch.player.follow.clip_follow`) of the clip
    ``clips[f]`` as ``prt play --clip`` plays it, at its frame ``frame_index[f]``: ``plans[name]`` is the clip's
    :class:`~prt_torch.rig.load.PlanClip`-like entry (``.clip`` the frames played, ``.frame_index`` their indices in
    the source clip, ascending), so a frame of a split's frame range is framed as the player frames that range. Every
    image of a clip's frames is thereby framed as the player frames that frame (the image-PSNR camera contract)."""
    from prt_torch.player.follow import clip_follow
    from prt_torch.player.player import camera_eye
    from prt_torch.shapes import check_shape

    frame_index = np.asarray(frame_index, dtype=np.int64)
    check_shape(frame_index, "F", name="clip cameras: frame_index", dims={"F": len(clips)})
    out: list[Camera | None] = [None] * len(clips)
    for name in dict.fromkeys(clips):
        plan = plans[name]
        track = clip_follow(character, plan.clip)
        sel = np.flatnonzero([c == name for c in clips])
        src = np.asarray(plan.frame_index, dtype=np.int64)
        at = np.minimum(np.searchsorted(src, frame_index[sel]), len(src) - 1)
        check(bool(np.all(src[at] == frame_index[sel])), f"clip cameras: frames of {name!r} outside its clip")
        for i, a in zip(sel, at, strict=True):
            c, r = track.at(int(a))
            out[i] = Camera(np.asarray(camera_eye(c, r), np.float64), np.asarray(c, np.float64), tuple(window_hw))
    return [c for c in out if c is not None]


def player_camera(character: Any, window_hw: tuple[int, int] = WINDOW_HW,
                  positions: np.ndarray | None = None) -> Camera:
    """The camera :class:`prt_torch.player.Player` uses for ``character`` at its default azimuth and
    elevation (the player's own :func:`~prt_torch.player.player.camera_target` and
    :func:`~prt_torch.player.player.camera_eye`; no exported run needed). ``positions (F, V, 3)``: a deformable
    sequence, framed as the deformable player frames it (:func:`~prt_torch.player.player.sequence_view`)."""
    from prt_torch.player.player import CAMERA_AZIMUTH, camera_eye, camera_target, sequence_view

    if positions is None:
        (center, radius), azimuth = camera_target(character.rest_vertices), CAMERA_AZIMUTH
    else:
        center, radius, azimuth = sequence_view(positions, character.faces)
    eye = camera_eye(center, radius, azimuth)
    return Camera(np.asarray(eye, dtype=np.float64), np.asarray(center, dtype=np.float64), tuple(window_hw))


class ImageRenderer:
    """The player's :class:`~prt_torch.player.render.MeshRenderer` at the player's camera, plus the mask rule.

    Args:
        rest_vertices: ``(V, 3)``; faces: ``(T, 3)`` of the character.
        camera: :func:`player_camera`.
        albedo: the character's base colour (:func:`prt_torch.player.material.surface_albedo`); ``None``: white.
    """

    BACKGROUND = (0.08, 0.08, 0.1)  # the MeshRenderer default (the player's)

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, camera: Camera,
                 albedo: SurfaceAlbedo | None = None) -> None:
        from prt_torch.player.render import MeshRenderer, has_display, quiet_vtk_display_probe

        if not has_display():
            quiet_vtk_display_probe()
        h, w = camera.window_hw
        self.camera = camera
        self.albedo = albedo
        tex = albedo is not None and albedo.texture is not None
        self.renderer = MeshRenderer(rest_vertices, faces, window_size=(w, h), off_screen=True,
                                     uv=albedo.uv if tex else None, texture=albedo.texture if tex else None)
        self.set_camera(camera)
        self.n_vertices = int(np.asarray(rest_vertices).shape[0])
        self._white = np.full((self.n_vertices, 3), 255, np.uint8)

    def set_camera(self, camera: Camera) -> None:
        """Render from ``camera`` from now on (a frame's :func:`clip_cameras` entry; same window size)."""
        from prt_torch.errors import PrtError

        if tuple(camera.window_hw) != tuple(self.camera.window_hw):
            raise PrtError(f"image camera window {camera.window_hw} differs from the renderer's "
                           f"{self.camera.window_hw}")
        self.camera = camera
        self.renderer.set_camera(camera.eye, camera.center)

    def surface(self, radiance: np.ndarray) -> np.ndarray:
        """The surface radiance ``(..., V, 3)`` of ``radiance (..., V, 3)``: times the per-vertex base colour
        (:meth:`prt_torch.player.material.SurfaceAlbedo.apply`; the array itself without an albedo)."""
        return radiance if self.albedo is None else self.albedo.apply(radiance)

    def render(self, positions: np.ndarray, colors: np.ndarray, radiance: np.ndarray | None = None,
               tonemap: Any = None) -> np.ndarray:
        """``(H, W, 3)`` uint8 image of the mesh at ``positions (V, 3)`` with vertex ``colors (V, 3)`` uint8; a
        textured character's interior pixels are shaded per pixel from the linear ``radiance (V, 3)`` (without
        its base colour) and ``tonemap`` when given."""
        self.renderer.update(np.asarray(positions, dtype=np.float32), colors, radiance=radiance, tonemap=tonemap)
        return self.renderer.render()

    def render_radiance(self, positions: np.ndarray, radiance: np.ndarray, tonemap: Any) -> np.ndarray:
        """The player's image of ``radiance (V, 3)`` (linear, without the base colour) at ``positions (V, 3)``
        under ``tonemap``: vertex colours ``tonemap(surface(radiance))``, textured pixels per pixel."""
        r = np.asarray(radiance)
        per_pixel = self.albedo is not None and self.albedo.texture is not None
        return self.render(positions, tonemap(self.surface(r)), radiance=r if per_pixel else None,
                           tonemap=tonemap if per_pixel else None)

    def mask(self, positions: np.ndarray) -> np.ndarray:
        """``(H, W)`` bool: pixels fully covered by the mesh (white vertices on black read 255 everywhere)."""
        pl = self.renderer.plotter
        pl.set_background((0.0, 0.0, 0.0))
        try:
            img = self.render(positions, self._white)
        finally:
            pl.set_background(self.BACKGROUND)
        return (img == 255).all(axis=-1)

    def frame_images(self, positions: np.ndarray, radiance: Mapping[str, np.ndarray], truth: str,
                     mask: np.ndarray | None = None) -> FrameImages:
        """Render every ``radiance[name] (V, 3)`` (linear, without the base colour) with ONE tone map fixed from
        the truth's surface radiance ``surface(radiance[truth])`` (the player's rule); images, mask and the image
        SSE of each entry vs the truth."""
        from prt_torch.player.tonemap import auto_tonemap

        tm = auto_tonemap(self.surface(radiance[truth]))
        m = self.mask(positions) if mask is None else mask
        imgs = {name: self.render_radiance(positions, r, tm) for name, r in radiance.items()}
        sse = {name: image_sse(img, imgs[truth], m) for name, img in imgs.items()}
        return FrameImages(imgs, m, sse, tm)

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> ImageRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class FrameImages:
    """One frame's images ``{name: (H, W, 3) uint8}``, its mask ``(H, W)``, ``{name: (sse, n)}`` vs the truth
    and the tone map used (:class:`prt_torch.player.tonemap.ToneMap`)."""

    images: dict[str, np.ndarray]
    mask: np.ndarray
    sse: dict[str, tuple[float, int]]
    tonemap: Any
