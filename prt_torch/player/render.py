"""Offscreen (or windowed) pyvista rendering of a per-vertex-coloured triangle mesh.

The plotter and the mesh are built once; each frame only the point coordinates and the RGB
colours are overwritten in place (:meth:`MeshRenderer.update`), then :meth:`MeshRenderer.render`
returns the image. VTK lighting is off: the colours *are* the shading.
"""

from __future__ import annotations

import os

import numpy as np

from prt_torch.errors import PrtError


def _faces_vtk(faces: np.ndarray) -> np.ndarray:
    f = np.asarray(faces, dtype=np.int64)
    return np.hstack([np.full((len(f), 1), 3, dtype=np.int64), f]).ravel()


def has_display() -> bool:
    """Whether an interactive window can be opened (X11/Wayland display present)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _quiet_vtk_display_probe() -> None:
    """Headless: VTK logs "bad X server connection" before falling back to EGL; keep only its errors."""
    try:
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    except (ImportError, AttributeError):  # an older VTK without vtkLogger: the warning is harmless
        pass


class MeshRenderer:
    """A pyvista plotter showing one mesh coloured per vertex.

    Args:
        vertices: ``(V, 3)`` initial positions (world, z up).
        faces: ``(T, 3)`` triangle indices.
        window_size: ``(width, height)`` in pixels.
        off_screen: render without a window (PNG/MP4 output); ``False`` opens a window.
        background: RGB in [0, 1].
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, window_size: tuple[int, int] = (640, 480),
                 off_screen: bool = True, background: tuple[float, float, float] = (0.08, 0.08, 0.1)) -> None:
        import pyvista as pv

        if off_screen and not has_display():
            _quiet_vtk_display_probe()
        vertices = np.asarray(vertices, dtype=np.float32)
        faces = np.asarray(faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise PrtError(f"renderer vertices must have shape (V, 3), got {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise PrtError(f"renderer faces must have shape (T, 3) with T > 0, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise PrtError(f"renderer faces index outside 0..{len(vertices) - 1}")
        self.n_vertices = len(vertices)
        self.mesh = pv.PolyData(vertices.copy(), _faces_vtk(faces))
        self.mesh.point_data["rgb"] = np.zeros((self.n_vertices, 3), dtype=np.uint8)
        self.plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
        self.plotter.set_background(background)
        self.plotter.add_mesh(self.mesh, scalars="rgb", rgb=True, lighting=False, show_scalar_bar=False)
        self.off_screen = off_screen
        self._points = self.mesh.points  # a numpy view onto the VTK array
        self._rgb = self.mesh.point_data["rgb"]

    def set_camera(self, eye: np.ndarray, target: np.ndarray, up: tuple[float, float, float] = (0.0, 0.0, 1.0),
                   view_angle: float = 30.0) -> None:
        """Place the camera at ``eye`` looking at ``target`` (world, z up)."""
        cam = self.plotter.camera
        cam.position = tuple(float(x) for x in eye)
        cam.focal_point = tuple(float(x) for x in target)
        cam.up = up
        cam.view_angle = view_angle
        self.plotter.reset_camera_clipping_range()

    def update(self, vertices: np.ndarray, colors: np.ndarray) -> None:
        """Overwrite positions ``(V, 3)`` and colours ``(V, 3)`` uint8 (or float in [0, 1]) in place."""
        if vertices.shape != (self.n_vertices, 3) or colors.shape != (self.n_vertices, 3):
            raise PrtError(f"renderer update needs (V, 3) positions and colours with V={self.n_vertices}, "
                           f"got {vertices.shape} and {colors.shape}")
        if colors.dtype != np.uint8:
            colors = (np.clip(colors, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        self._points[:] = vertices
        self._rgb[:] = colors
        self.mesh.points = self._points  # marks the VTK arrays modified
        self.mesh.point_data["rgb"] = self._rgb
        self.plotter.reset_camera_clipping_range()

    def render(self) -> np.ndarray:
        """Render and return the image ``(H, W, 3)`` uint8."""
        self.plotter.render()
        img = self.plotter.screenshot(return_img=True)
        return np.ascontiguousarray(img[..., :3])

    def close(self) -> None:
        self.plotter.close()

    def __enter__(self) -> MeshRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
