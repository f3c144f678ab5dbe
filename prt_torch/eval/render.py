"""Off-screen pyvista image of one frame shaded by several visibilities (seed 000 Fig. 5 layout).

Baked radiance is shown as per-vertex RGB (``scalars=colors, rgb=True``) with VTK lighting off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prt_torch.errors import check
from prt_torch.io import atomic_path


def tonemap(radiance: np.ndarray, white: float) -> np.ndarray:
    """Linear radiance ``(V, 3)`` -> uint8 sRGB-ish colours (scale to ``white``, gamma 2.2)."""
    x = np.clip(np.asarray(radiance) / max(white, 1e-12), 0.0, 1.0) ** (1 / 2.2)
    return (x * 255 + 0.5).astype(np.uint8)


def render_panels(positions: np.ndarray, faces: np.ndarray, radiances: dict[str, np.ndarray], path: Path,
                  size: tuple[int, int] = (320, 420), view: np.ndarray | None = None) -> Path:
    """One row of panels, one per entry of ``radiances`` (``(V, 3)`` each), written as PNG."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    check(faces.ndim == 2 and faces.shape[1] == 3 and len(faces) > 0, "render: need (T, 3) triangle faces")
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    names = list(radiances)
    white = float(np.percentile(np.asarray(radiances[names[0]]).max(axis=1), 99))
    pl = pv.Plotter(off_screen=True, shape=(1, len(names)), window_size=(size[0] * len(names), size[1]),
                    border=False)
    center = positions.mean(0)
    extent = float(np.linalg.norm(positions.max(0) - positions.min(0)))
    v = np.array([0.3, -1.0, 0.35]) if view is None else np.asarray(view)
    v = v / np.linalg.norm(v)
    for i, name in enumerate(names):
        pl.subplot(0, i)
        mesh = pv.PolyData(positions, cells)
        pl.add_mesh(mesh, scalars=tonemap(radiances[name], white), rgb=True, lighting=False, show_scalar_bar=False)
        pl.add_text(name, font_size=10, color="black")
        pl.set_background("white")
        pl.camera_position = [tuple(center + v * extent * 1.6), tuple(center), (0.0, 0.0, 1.0)]
    with atomic_path(path) as tmp:
        pl.screenshot(str(tmp))
    pl.close()
    return path
