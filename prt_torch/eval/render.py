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
                  size: tuple[int, int] = (320, 420), view: np.ndarray | None = None,
                  diff_scale: float | None = 4.0) -> Path:
    """Panels, one per entry of ``radiances`` (``(V, 3)`` each; the first is the reference), written
    as PNG. With ``diff_scale`` a second row shows ``diff_scale x |L - L_ref|`` per panel (seed 000
    Fig. 5's scaled-difference insets) on the same white point."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    check(faces.ndim == 2 and faces.shape[1] == 3 and len(faces) > 0, "render: need (T, 3) triangle faces")
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    names = list(radiances)
    white = float(np.percentile(np.asarray(radiances[names[0]]).max(axis=1), 99))
    rows = 2 if diff_scale else 1
    pl = pv.Plotter(off_screen=True, shape=(rows, len(names)), window_size=(size[0] * len(names), size[1] * rows),
                    border=False)
    ref = np.asarray(radiances[names[0]])
    center = positions.mean(0)
    extent = float(np.linalg.norm(positions.max(0) - positions.min(0)))
    v = np.array([0.3, -1.0, 0.35]) if view is None else np.asarray(view)
    v = v / np.linalg.norm(v)
    for row in range(rows):
        for i, name in enumerate(names):
            pl.subplot(row, i)
            mesh = pv.PolyData(positions, cells)
            rad = np.asarray(radiances[name])
            colors = tonemap(rad, white) if row == 0 else tonemap(diff_scale * np.abs(rad - ref), white)
            pl.add_mesh(mesh, scalars=colors, rgb=True, lighting=False, show_scalar_bar=False)
            label = name if row == 0 else f"{diff_scale:g}x |{name} - {names[0]}|"
            pl.add_text(label, font_size=9, color="black" if row == 0 else "white")
            pl.set_background("white" if row == 0 else "black", all_renderers=False)
            pl.camera_position = [tuple(center + v * extent * 1.6), tuple(center), (0.0, 0.0, 1.0)]
    with atomic_path(path) as tmp:
        pl.screenshot(str(tmp))
    pl.close()
    return path
