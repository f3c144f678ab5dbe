"""Offscreen (or windowed) pyvista rendering of a per-vertex-coloured triangle mesh.

The plotter and the mesh are built once; each frame only the point coordinates and the RGB
colours are overwritten in place (:meth:`MeshRenderer.update`), then :meth:`MeshRenderer.render`
returns the image. VTK lighting is off: the colours *are* the shading.

Several meshes (a scene: characters and the ground) share one plotter: the constructor's mesh is mesh 0,
:meth:`MeshRenderer.add_mesh` adds more and returns their index, and :meth:`MeshRenderer.update` takes the
index of the mesh to overwrite (default 0, so single-mesh callers are unchanged).

Textured meshes (a character's base-colour texture, :mod:`prt_torch.player.material`) are shaded PER PIXEL
exactly: ``pixel = tonemap(interp(L) * base(interp(uv)))`` with ``L`` the linear radiance per vertex, ``uv`` the
per-corner texture coordinates, ``base`` the linear base-colour texture (bilinear, repeat:
:func:`prt_torch.rig.material.sample_linear`) and ``tonemap`` the player's (:mod:`prt_torch.player.tonemap`, the one
rule). VTK can only multiply a texture into colours AFTER the tone map (8-bit, display space), which is wrong
wherever the texture is darker than the tone-mapped light (it clips), so it is not used for this. Instead
:meth:`MeshRenderer.render` draws a second, hidden pass of every mesh with flat triangle-id colours (no
anti-aliasing, its own offscreen window, the same camera), finds each textured pixel's triangle there,
intersects the pixel's camera ray with that triangle for perspective-correct barycentrics, and computes the
pixel in numpy. The pixels on a textured mesh's silhouette keep the anti-aliased per-vertex colours of the
main pass (the colours :meth:`update` was given). A window (``off_screen=False``) shows the per-vertex colours.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape

#: the largest triangle id the id pass encodes (24-bit colours; 0 is the background)
MAX_ID = (1 << 24) - 1


def _faces_vtk(faces: np.ndarray) -> np.ndarray:
    f = np.asarray(faces, dtype=np.int64)
    return np.hstack([np.full((len(f), 1), 3, dtype=np.int64), f]).ravel()


def has_display() -> bool:
    """Whether an interactive window can be opened (X11/Wayland display present)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def quiet_vtk_display_probe() -> None:
    """Headless: VTK logs "bad X server connection" before falling back to EGL; keep only its errors."""
    try:
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    except (ImportError, AttributeError):  # an older VTK without vtkLogger: the warning is harmless
        pass


@dataclass
class _Texturing:
    """A textured mesh's per-pixel inputs: ``uv (T, 3, 2)``, linear ``base (H, W, 3)`` float32, and (per frame)
    the linear radiance ``(V, 3)`` and tone map given to :meth:`MeshRenderer.update`."""

    uv: np.ndarray
    base: np.ndarray
    radiance: np.ndarray | None = None
    tonemap: Callable[[np.ndarray], np.ndarray] | None = None


def _id_colors(first: int, count: int) -> np.ndarray:
    """``(count, 3)`` uint8 colours encoding the ids ``first + 1 .. first + count`` (24-bit, red the low byte)."""
    ids = np.arange(first + 1, first + count + 1, dtype=np.uint32)
    return np.stack([ids & 255, (ids >> 8) & 255, (ids >> 16) & 255], 1).astype(np.uint8)


def _decode_ids(img: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` uint8 id image -> ``(H, W)`` int32 ids (0: background)."""
    rgba = np.zeros(img.shape[:2] + (4,), np.uint8)
    rgba[..., :3] = img
    return rgba.view("<u4")[..., 0].astype(np.int32)


def camera_rays(camera, width: int, height: int, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(eye (3,), directions (N, 3))`` world-space unit rays of a VTK perspective camera through the centres of
    pixels ``(rows, cols)`` (row 0 = the top of the image, as :meth:`MeshRenderer.render` returns it)."""
    eye = np.asarray(camera.position, dtype=np.float64)
    fwd = np.asarray(camera.focal_point, dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(camera.up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    th = np.tan(np.radians(camera.view_angle) / 2.0)
    x = (2.0 * (cols + 0.5) / width - 1.0) * th * width / height
    y = (1.0 - 2.0 * (rows + 0.5) / height) * th
    d = fwd + x[:, None] * right + y[:, None] * up
    return eye, d / np.sqrt(np.einsum("nc,nc->n", d, d))[:, None]


def ray_barycentrics(eye: np.ndarray, dirs: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                     p2: np.ndarray) -> np.ndarray:
    """``(N, 3)`` barycentrics of the hits of rays ``eye + t dirs (N, 3)`` with the planes of triangles
    ``(p0, p1, p2)`` (each ``(N, 3)``; Moller-Trumbore), clipped onto the triangle (a pixel the rasteriser gave a
    triangle may sit a hair outside it)."""
    e1, e2 = p1 - p0, p2 - p0
    pv = np.cross(dirs, e2)
    det = np.einsum("nc,nc->n", e1, pv)
    det = np.where(np.abs(det) < 1e-20, 1e-20, det)
    tv = eye - p0
    u = np.einsum("nc,nc->n", tv, pv) / det
    v = np.einsum("nc,nc->n", dirs, np.cross(tv, e1)) / det
    b = np.clip(np.stack([1.0 - u - v, u, v], 1), 0.0, None)
    return b / np.maximum(b.sum(1, keepdims=True), 1e-12)


class MeshRenderer:
    """A pyvista plotter showing one mesh (or several: :meth:`add_mesh`) coloured per vertex, textured meshes
    shaded per pixel (module docstring).

    Args:
        vertices: ``(V, 3)`` initial positions (world, z up).
        faces: ``(T, 3)`` triangle indices.
        window_size: ``(width, height)`` in pixels.
        off_screen: render without a window (PNG/MP4 output); ``False`` opens a window.
        background: RGB in [0, 1].
        uv, texture: mesh 0's per-corner texture coordinates ``(T, 3, 2)`` and LINEAR base colour
            ``(H, W, 3)`` float (:meth:`add_mesh`); ``None``: per-vertex colours only.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, window_size: tuple[int, int] = (640, 480),
                 off_screen: bool = True, background: tuple[float, float, float] = (0.08, 0.08, 0.1),
                 uv: np.ndarray | None = None, texture: np.ndarray | None = None) -> None:
        import pyvista as pv

        if off_screen and not has_display():
            quiet_vtk_display_probe()
        self.plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
        self.plotter.set_background(background)
        self.off_screen = off_screen
        self.window_size = (int(window_size[0]), int(window_size[1]))
        self.meshes: list = []  # pv.PolyData per mesh
        self._views: list[tuple[np.ndarray, np.ndarray]] = []  # (points, rgb) numpy views per mesh
        self._faces: list[np.ndarray] = []
        self._texturing: list[_Texturing | None] = []
        self._id_plotter = None  # the hidden triangle-id pass (built on the first textured render)
        self._id_meshes: list = []
        self.add_mesh(vertices, faces, uv=uv, texture=texture)
        self.n_vertices = self.vertex_counts[0]
        self.mesh = self.meshes[0]

    @property
    def vertex_counts(self) -> list[int]:
        """Vertices of each mesh, in :meth:`add_mesh` order."""
        return [int(m.n_points) for m in self.meshes]

    def add_mesh(self, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None = None,
                 texture: np.ndarray | None = None) -> int:
        """Add a per-vertex-coloured mesh ``vertices (V, 3)``, ``faces (T, 3)``; returns its index.

        With per-corner ``uv (T, 3, 2)`` (glTF: ``v`` down from the texture's top row) and a LINEAR base colour
        ``texture (H, W, 3)`` float, :meth:`render` shades the mesh per pixel from the linear radiance given to
        :meth:`update` (module docstring)."""
        import pyvista as pv

        vertices = np.asarray(vertices, dtype=np.float32)
        faces = np.asarray(faces)
        check_shape(vertices, "V 3", name="renderer vertices")
        check_shape(faces, "T 3", name="renderer faces")
        if len(faces) == 0:
            raise PrtError(f"renderer faces must have shape (T, 3) with T > 0, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise PrtError(f"renderer faces index outside 0..{len(vertices) - 1}")
        tx = None
        if (uv is None) != (texture is None):
            raise PrtError("a textured renderer mesh needs both uv (T, 3, 2) and a base-colour texture (H, W, 3)")
        if texture is not None:
            uv = np.asarray(uv, dtype=np.float64)
            base = np.asarray(texture, dtype=np.float32)
            if uv.shape != (len(faces), 3, 2) or not np.isfinite(uv).all():
                raise PrtError(f"renderer uv must be finite (T, 3, 2) with T={len(faces)}, got {uv.shape}")
            if base.ndim != 3 or base.shape[2] != 3 or 0 in base.shape or not np.isfinite(base).all():
                raise PrtError(f"renderer texture must be a finite linear (H, W, 3) base colour, got {base.shape}")
            tx = _Texturing(uv, base)
        if sum(len(f) for f in self._faces) + len(faces) > MAX_ID:
            raise PrtError(f"renderer: more than {MAX_ID} triangles in all")
        mesh = pv.PolyData(vertices.copy(), _faces_vtk(faces))
        mesh.point_data["rgb"] = np.zeros((len(vertices), 3), dtype=np.uint8)
        self.plotter.add_mesh(mesh, scalars="rgb", rgb=True, lighting=False, show_scalar_bar=False)
        self.meshes.append(mesh)
        self._views.append((mesh.points, mesh.point_data["rgb"]))  # numpy views onto the VTK arrays
        self._faces.append(faces.astype(np.intp))
        self._texturing.append(tx)
        if self._id_plotter is not None:  # keep the id pass complete
            self._add_id_mesh(len(self.meshes) - 1)
        return len(self.meshes) - 1

    def set_camera(self, eye: np.ndarray, target: np.ndarray, up: tuple[float, float, float] = (0.0, 0.0, 1.0),
                   view_angle: float = 30.0) -> None:
        """Place the camera at ``eye`` looking at ``target`` (world, z up)."""
        cam = self.plotter.camera
        cam.position = tuple(float(x) for x in eye)
        cam.focal_point = tuple(float(x) for x in target)
        cam.up = up
        cam.view_angle = view_angle
        self.plotter.reset_camera_clipping_range()

    def update(self, vertices: np.ndarray, colors: np.ndarray, index: int = 0, radiance: np.ndarray | None = None,
               tonemap: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        """Overwrite positions ``(V, 3)`` and colours ``(V, 3)`` uint8 (or float in [0, 1]) of mesh ``index``
        in place. A textured mesh also takes the LINEAR radiance ``(V, 3)`` and the tone map (linear ``(..., 3)``
        -> uint8) for its per-pixel shading; other meshes ignore them."""
        if not 0 <= index < len(self.meshes):
            raise PrtError(f"renderer has {len(self.meshes)} meshes, no mesh {index}")
        mesh = self.meshes[index]
        points, rgb = self._views[index]
        n = len(points)
        if vertices.shape != (n, 3) or colors.shape != (n, 3):
            raise PrtError(f"renderer update needs (V, 3) positions and colours with V={n}, "
                           f"got {vertices.shape} and {colors.shape}")
        if colors.dtype != np.uint8:
            colors = (np.clip(colors, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        points[:] = vertices
        rgb[:] = colors
        mesh.points = points  # marks the VTK arrays modified
        mesh.point_data["rgb"] = rgb
        tx = self._texturing[index]
        if tx is not None:
            if radiance is not None and (tonemap is None or np.shape(radiance) != (n, 3)):
                raise PrtError(f"renderer update: a textured mesh's radiance must be (V, 3) with V={n}, with a "
                               f"tone map")
            tx.radiance = None if radiance is None else np.asarray(radiance, dtype=np.float32)
            tx.tonemap = tonemap
        self.plotter.reset_camera_clipping_range()

    # -- the per-pixel pass of textured meshes ------------------------------------------------------------------
    def _add_id_mesh(self, index: int) -> None:
        import pyvista as pv

        first = sum(len(f) for f in self._faces[:index])
        faces = self._faces[index]
        mesh = pv.PolyData(np.asarray(self.meshes[index].points).copy(), _faces_vtk(faces))
        mesh.cell_data["id"] = _id_colors(first, len(faces))
        self._id_plotter.add_mesh(mesh, scalars="id", rgb=True, lighting=False, show_scalar_bar=False,
                                  preference="cell", interpolate_before_map=False)
        self._id_meshes.append(mesh)

    def _id_pass(self) -> np.ndarray:
        """``(H, W)`` id image: 0 background, else ``1 +`` the triangle's index over all meshes in order."""
        import pyvista as pv

        if self._id_plotter is None:
            self._id_plotter = pv.Plotter(off_screen=True, window_size=list(self.window_size))
            self._id_plotter.set_background((0.0, 0.0, 0.0))
            self._id_plotter.disable_anti_aliasing()
            self._id_plotter.render_window.SetMultiSamples(0)
            for i in range(len(self.meshes)):
                self._add_id_mesh(i)
        for mesh, id_mesh in zip(self.meshes, self._id_meshes, strict=True):
            id_mesh.points = np.asarray(mesh.points)
        src, dst = self.plotter.camera, self._id_plotter.camera
        dst.position, dst.focal_point, dst.up = src.position, src.focal_point, src.up
        dst.view_angle = src.view_angle
        dst.clipping_range = src.clipping_range
        self._id_plotter.render()
        return _decode_ids(self._id_plotter.screenshot(return_img=True)[..., :3])

    def _shade_textured(self, img: np.ndarray) -> np.ndarray:
        from prt_torch.rig.material import sample_linear

        ids = self._id_pass()
        h, w = ids.shape
        if img.shape[:2] != (h, w):
            raise PrtError(f"renderer: id pass {ids.shape} and image {img.shape[:2]} differ in size")
        # which mesh each pixel shows (-1: background); interior pixels of a mesh only: the silhouette keeps the
        # main pass's anti-aliased per-vertex colours
        ends = np.cumsum([len(f) for f in self._faces])
        which = np.where(ids > 0, np.searchsorted(ends, ids - 1, side="right"), -1)
        pad = np.pad(which, 1, mode="edge")
        inner = ((pad[1:-1, :-2] == which) & (pad[1:-1, 2:] == which) & (pad[:-2, 1:-1] == which)
                 & (pad[2:, 1:-1] == which))
        out = img.copy()
        first = 0
        for mesh, faces, tx in zip(self.meshes, self._faces, self._texturing, strict=True):
            lo, first = first, first + len(faces)
            if tx is None or tx.radiance is None:
                continue
            sel = inner & (ids > lo) & (ids <= first)
            if not sel.any():
                continue
            rows, cols = np.nonzero(sel)
            tri = ids[rows, cols] - lo - 1
            fv = faces[tri]
            pts = np.asarray(mesh.points, dtype=np.float64)
            eye, dirs = camera_rays(self.plotter.camera, w, h, rows, cols)
            b = ray_barycentrics(eye, dirs, pts[fv[:, 0]], pts[fv[:, 1]], pts[fv[:, 2]])
            radiance = np.einsum("nk,nkc->nc", b, tx.radiance[fv])
            base = sample_linear(tx.base, np.einsum("nk,nkc->nc", b, tx.uv[tri]))
            out[rows, cols] = tx.tonemap(radiance * base)
        return out

    def render(self) -> np.ndarray:
        """Render and return the image ``(H, W, 3)`` uint8 (textured meshes shaded per pixel)."""
        self.plotter.render()
        img = np.ascontiguousarray(self.plotter.screenshot(return_img=True)[..., :3])
        if any(t is not None and t.radiance is not None for t in self._texturing):
            img = self._shade_textured(img)
        return img

    def close(self) -> None:
        self.plotter.close()
        if self._id_plotter is not None:
            self._id_plotter.close()
            self._id_plotter = None

    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
