"""The float32 vertex-last posing path against the library's reference functions, and the
lighting / tone-mapping helpers against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.player.lighting import hemisphere_visibility, lighting_from_sh, sinc_window
from prt_torch.player.posing import Poser
from prt_torch.player.tonemap import auto_tonemap, to_colors
from prt_torch.rig.builtin import make_character
from prt_torch.rig.vertex_frames import cluster_axes, cluster_bones, vertex_frames


@pytest.fixture(scope="module")
def character():
    return make_character(density=0.08)


def test_poser_matches_reference_fk_lbs_frames_features(character) -> None:
    ch = character
    labels = np.unique(np.argmax(ch.dense_weights, axis=1), return_inverse=True)[1].astype(np.int32)
    axes, bones = cluster_axes(ch.rest_vertices, labels), cluster_bones(ch.dense_weights, labels)
    poser = Poser(ch, labels, axes, bones)
    clip = ch.clips["jumping_jacks"]
    idx = np.array([0, 5, 17, 30])
    eye = np.array([0.3, -4.0, 1.2])
    pb = poser(clip.local[idx], eye)
    ref = ch.pose(clip)
    pos, nrm = ch.skin_mesh(ref.skin[idx])
    frames = vertex_frames(nrm, ref.skin[idx], labels, axes, bones)
    np.testing.assert_allclose(pb.positions.transpose(0, 2, 1), pos, atol=2e-5)
    np.testing.assert_allclose(pb.normals.transpose(0, 2, 1), nrm, atol=2e-5)
    np.testing.assert_allclose(pb.frames_vx33(), frames, atol=2e-4)
    np.testing.assert_allclose(pb.features, ref.features[idx], atol=1e-6)
    view = eye[None, None] - pos
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    np.testing.assert_allclose(pb.view_dirs.transpose(0, 2, 1), view, atol=2e-5)
    f = pb.frames_vx33()
    np.testing.assert_allclose(f @ f.transpose(0, 1, 3, 2), np.broadcast_to(np.eye(3), f.shape), atol=1e-5)
    assert np.all(np.linalg.det(f) > 0.999)
    with pytest.raises(PrtError, match="B >= 1"):
        poser(clip.local[:0], eye)


def test_hemisphere_visibility_closed_form() -> None:
    v = hemisphere_visibility(4)
    assert v[0] == pytest.approx(np.sqrt(np.pi), rel=1e-6)  # 2 pi * Y00
    assert v[2] == pytest.approx(np.sqrt(3 * np.pi) / 2, rel=1e-6)  # 2 pi int_0^1 sqrt(3/4pi) z dz
    assert v[6] == pytest.approx(0.0, abs=1e-7)  # P2 integrates to 0 over [0, 1]
    assert v[12] == pytest.approx(-np.sqrt(7 * np.pi) / 8, rel=1e-6)  # 2 pi sqrt(7/4pi) int_0^1 P3
    assert np.count_nonzero(np.abs(v) > 1e-6) == 3


def test_lighting_window_and_fit_errors() -> None:
    w = sinc_window(4)
    assert w[0] == 1.0 and w[1] == pytest.approx(np.sinc(0.25)) and w[15] == pytest.approx(np.sinc(0.75))
    with pytest.raises(PrtError, match=r"\(C, 3\)"):
        lighting_from_sh(np.zeros((16, 2)))
    with pytest.raises(PrtError, match="NaN"):
        lighting_from_sh(np.full((16, 3), np.nan))


def test_tonemap() -> None:
    r = np.array([[0.0, 0.5, 1.0], [2.0, -1.0, 4.0]], np.float32)
    c = to_colors(r, 1.0)
    assert c.dtype == np.uint8 and c[0, 0] == 0 and c[0, 2] == 255 and c[1, 1] == 0 and c[1, 2] == 255
    assert c[0, 1] == round(255 * 0.5 ** (1 / 2.2))
    # Reinhard extended: white maps to 1, small values ~ linear, monotone
    x = np.array([[0.01, 0.5, 4.0]], np.float32)
    c = to_colors(x, 1.0, white=4.0)
    assert c[0, 2] == 255 and c[0, 0] == round(255 * (0.01 * (1 + 0.01 / 16) / 1.01) ** (1 / 2.2))
    assert c[0, 1] == round(255 * (0.5 * (1 + 0.5 / 16) / 1.5) ** (1 / 2.2))
    rad = np.random.default_rng(0).uniform(0.0, 10.0, size=(1000, 3)).astype(np.float32)
    tm = auto_tonemap(rad)
    m = rad.max(-1)
    assert tm.exposure == pytest.approx(0.3 / np.median(m), rel=1e-5)
    assert tm.white == pytest.approx(max(np.percentile(m, 99.5) * tm.exposure, 1.0), rel=1e-5)
