"""The deformable camera rule (prt_torch.player.player.facing_azimuth / sequence_view): the camera sits on the
side a moving surface's front faces, checked against sheets whose normal is known in closed form."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from prt_torch.player.player import CAMERA_AZIMUTH, camera_eye, facing_azimuth, sequence_view


def _sheet(azimuth: float, n: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A vertical unit sheet (counter-clockwise faces) whose front normal is (sin a, -cos a, 0)."""
    u, w = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(0.0, 1.0, n), indexing="ij")
    # in the x-z plane the front normal of (x right, z up) faces -y when wound (x, z) counter-clockwise from -y
    pts = np.stack([u.ravel(), np.zeros(u.size), w.ravel()], -1)
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + n, i.ravel() + n + 1, i.ravel() + 1
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    normal = trimesh.Trimesh(pts, faces, process=False).face_normals.mean(0)
    if normal[1] > 0:  # make the front face -y (camera_eye's azimuth 0)
        faces = faces[:, ::-1]
    rot = np.array([[np.cos(azimuth), -np.sin(azimuth), 0.0], [np.sin(azimuth), np.cos(azimuth), 0.0], [0, 0, 1]])
    return pts @ rot.T, faces


@pytest.mark.parametrize("azimuth", [0.0, 0.7, -2.0, 3.0])
def test_camera_faces_the_front_of_a_sheet(azimuth: float) -> None:
    pts, faces = _sheet(azimuth)
    frames = np.stack([pts, pts + [0.0, 0.0, 0.1]])  # (2, V, 3): a translated second frame changes nothing
    a = facing_azimuth(frames, faces)
    normal = trimesh.Trimesh(pts, faces, process=False).face_normals.mean(0)  # independent: trimesh's normals
    eye = camera_eye(np.zeros(3), 1.0, a, 0.0)
    assert np.dot(eye / np.linalg.norm(eye), normal / np.linalg.norm(normal)) == pytest.approx(1.0, abs=1e-6)
    # the reversed winding (the back side) puts the camera opposite
    b = facing_azimuth(frames, faces[:, ::-1])
    assert np.cos(b - a) == pytest.approx(-1.0, abs=1e-6)


def test_closed_surface_keeps_the_default_azimuth() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert facing_azimuth(sphere.vertices[None], sphere.faces) == CAMERA_AZIMUTH


def test_sequence_view_frames_every_position() -> None:
    pts, faces = _sheet(0.3)
    frames = np.stack([pts, pts + [2.0, 0.0, 0.0]])
    center, radius, _ = sequence_view(frames, faces)
    allp = frames.reshape(-1, 3)
    np.testing.assert_allclose(center, 0.5 * (allp.min(0) + allp.max(0)), atol=1e-6)
    assert radius == pytest.approx(float(np.linalg.norm(allp.max(0) - allp.min(0))), rel=1e-6)
