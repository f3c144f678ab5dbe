"""The cloth config (one-line errors), the input features and the air drag against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.cloth.config import WindPattern
from prt_torch.cloth.inputs import cloth_features
from prt_torch.cloth.subject import grid_faces
from prt_torch.cloth.wind import WindField, triangle_drag
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from tests.tolerance import assert_bitwise


@pytest.mark.parametrize(("cloth", "key"), [
    ({"scene": "flag"}, "train_winds"),  # a flag without wind
    ({"scene": "flag", "train_winds": [{"name": "a"}, {"name": "a"}]}, "used twice"),
    ({"scene": "cape", "train_winds": [{"name": "a"}]}, "scene 'flag'"),
    ({"scene": "flag", "append_pose": True, "train_winds": [{"name": "a"}]}, "append_pose"),
    ({"scene": "cape", "substeps": 0}, "cloth.substeps"),
    ({"scene": "cape", "young": float("nan")}, "cloth.young"),
    ({"scene": "cape", "poisson": 0.5}, "cloth.poisson"),
    ({"scene": "cape", "rows": 2}, "cloth.rows"),
    ({"scene": "sail"}, "cloth.scene"),
    ({"scene": "cape", "stiffness": 1.0}, "unknown config key 'cloth.stiffness'"),
    ({"scene": "flag", "train_winds": [{"name": "a", "speed": -1.0}]}, "cloth.train_winds.0.speed"),
])
def test_bad_config_is_one_line(cloth: dict, key: str) -> None:
    with pytest.raises(PrtError) as exc:
        config_from_dict({"name": "x", "cloth": cloth})
    assert key in str(exc.value) and "\n" not in str(exc.value)


def test_features_flat_sheet_and_appended_pose() -> None:
    from prt_torch.deform.mesh import interior_edges

    r, c = 4, 5
    x, z = np.meshgrid(np.arange(c, dtype=float), -np.arange(r, dtype=float))
    flat = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], -1)
    edges = interior_edges(grid_faces(r, c))
    frames = np.stack([flat, flat @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + 3.0])  # rigidly moved copy
    f = cloth_features(frames, edges)
    assert f.dtype == np.float32 and f.shape == (2, len(edges)) and np.allclose(f, 0.0, atol=1e-6)
    body = np.arange(6, dtype=np.float64).reshape(2, 3)
    g = cloth_features(frames, edges, body)
    assert g.shape == (2, len(edges) + 3)
    assert_bitwise(g[:, -3:], body.astype(np.float32), why="the body features are copied into the last columns")
    # fold the sheet 90 degrees along the column x = 2: every edge on the fold line reads +-pi/2, the rest 0
    folded = flat.copy()
    right = flat[:, 0] > 2
    folded[right, 1] = flat[right, 0] - 2
    folded[right, 0] = 2
    a = cloth_features(folded, edges)
    on_fold = (flat[edges[:, 0], 0] == 2) & (flat[edges[:, 1], 0] == 2)
    assert np.allclose(np.abs(a[on_fold]), np.pi / 2, atol=1e-5) and np.allclose(a[~on_fold], 0.0, atol=1e-6)
    with pytest.raises(PrtError):
        cloth_features(frames, edges, body[:1])


def test_drag_closed_form() -> None:
    # one triangle in the xz plane (area 1/2, normal +-y), wind U along +y: |F| = 1/2 rho C_d A U^2 along y
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]])
    faces = np.array([[0, 1, 2]])
    rho, cd, u = 1.2, 1.3, 5.0
    f = triangle_drag(x, np.zeros_like(x), faces, np.array([[0.0, u, 0]]), rho, cd, 0.0)
    assert np.allclose(f, [[0.0, 0.5 * rho * cd * 0.5 * u**2, 0.0]])
    # moving with the wind: no force; wind in the plane: only the tangential (skin friction) term
    assert np.allclose(triangle_drag(x, np.tile([0.0, u, 0], (3, 1)), faces, np.array([[0.0, u, 0]]), rho, cd, 0.1), 0)
    g = triangle_drag(x, np.zeros_like(x), faces, np.array([[u, 0.0, 0]]), rho, cd, 0.1)
    assert np.allclose(g, [[0.5 * rho * 0.1 * 0.5 * u**2, 0, 0]])


def test_wind_field_mean_and_bounds() -> None:
    p = WindPattern(name="w", speed=6.0, direction_deg=90.0, gust_amplitude=2.0, gust_direction_deg=0.0, seed=3)
    w = WindField.from_pattern(p, seed=0)
    pts = np.zeros((1, 3))
    v = np.array([w(pts, t)[0] for t in np.linspace(0.0, 200.0, 4001)])
    assert np.allclose(v[:, [0, 2]], 0.0, atol=1e-12)  # blows along +y only
    assert np.all(np.abs(v[:, 1] - 6.0) <= 2.0 + 1e-9) and abs(v[:, 1].mean() - 6.0) < 0.2
    assert_bitwise(w(pts, 1.5), WindField.from_pattern(p, seed=0)(pts, 1.5), why="the same seeded field twice")
    assert not np.array_equal(w(pts, 1.5), WindField.from_pattern(p, seed=1)(pts, 1.5))
