"""A game character of several meshes loads as one: a second skin over the same skeleton in its own mesh space, a
rigid part on a joint node without a skin, un-normalised weights (one warning line), a prop off the skeleton left
out (one warning line). The reference is the built-in character the file was written from
(:mod:`tests.rig.humanoid_synth`), posed by its own skinning."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from prt_torch.errors import PrtWarning
from prt_torch.rig.builtin import make_character
from prt_torch.rig.gltf import load_gltf
from tests.rig.humanoid_synth import helmet_rest, renamed, write_game_humanoid

FPS = 10.0
#: float32 file positions (~1 unit) through float32 inverse bind matrices and keyed transforms: a few ulps of 1
ATOL = 2e-5


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    c = make_character(0.05, fps=FPS)
    path = write_game_humanoid(tmp_path_factory.mktemp("multimesh") / "game.glb", c)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = load_gltf(path, fps=FPS)
    return c, g, [str(w.message) for w in caught if issubclass(w.category, PrtWarning)]


def test_meshes_merge_into_the_reference_character(pair: tuple) -> None:
    c, g, _ = pair
    assert sorted(g.joint_names) == sorted(renamed(n, k) for k, n in enumerate(c.joint_names))
    np.testing.assert_allclose(g.weights.sum(1), 1.0, atol=1e-6)
    d, idx = cKDTree(c.rest_vertices).query(g.rest_vertices)
    body = d < 1e-4
    helmet = ~body
    assert helmet.sum() == 8  # the box; the crate is left out
    assert np.array_equal(np.unique(idx[body]), np.arange(c.num_vertices))  # every reference vertex is there
    assert body.sum() - c.num_vertices <= 0.05 * c.num_vertices  # seam duplicates only where rounding splits them
    for name in c.clips:
        if name not in g.clips:
            continue
        got = g.skin_mesh(g.pose(name))[0]
        ref = c.skin_mesh(c.pose(name))[0]
        np.testing.assert_allclose(got[:, body], ref[:, idx[body]], atol=ATOL, err_msg=name)
    assert sorted(g.clips) == ["squat", "walk", "wave"]
    # the file's normals are kept although the helmet has none (float32 normals through float32 mesh spaces)
    np.testing.assert_allclose(g.rest_normals[body], c.rest_normals[idx[body]], atol=1e-5)


def test_rigid_part_follows_its_joint(pair: tuple) -> None:
    c, g, _ = pair
    rest = helmet_rest(c)
    d, idx = cKDTree(g.rest_vertices).query(rest)
    assert d.max() < ATOL
    head = c.joint_names.index("head")
    assert np.all(g.joints[idx, np.argmax(g.weights[idx], axis=1)] == g.joint_names.index(renamed("head", head)))
    assert np.allclose(g.weights[idx].max(axis=1), 1.0)
    clip = c.clips["wave"]
    world = clip.local.copy()  # the reference: the head's posed world transform times its inverse rest one
    for j, p in enumerate(c.parents):
        if p >= 0:
            world[:, j] = world[:, p] @ clip.local[:, j]
    bind = np.eye(4)
    j = head
    chain = []
    while j >= 0:
        chain.append(j)
        j = int(c.parents[j])
    for j in reversed(chain):
        bind = bind @ c.bind_local[j]
    outward = np.einsum("vi,vi->v", g.rest_normals[idx], rest - rest.mean(axis=0))
    assert np.all(outward > 0)  # the helmet's own normals (it has none in the file) point out of the box
    move = world[:, head] @ np.linalg.inv(bind)
    ref = np.einsum("fij,vj->fvi", move[:, :3, :3], rest) + move[:, None, :3, 3]
    got = g.skin_mesh(g.pose("wave"))[0][:, idx]
    np.testing.assert_allclose(got, ref, atol=ATOL)


def test_warnings_are_one_line_each(pair: tuple) -> None:
    _, _, messages = pair
    assert len(messages) == 2, messages
    assert all("\n" not in m for m in messages)
    assert any(m.startswith("game.glb: 1 mesh node(s) not part of the character, left out: 'Crate'") for m in messages)
    weights = [m for m in messages if "do not sum to 1" in m]
    assert len(weights) == 1 and weights[0].endswith("; normalised")


def test_a_skin_of_another_skeleton_is_left_out(tmp_path: Path) -> None:
    """The Arms mesh's skin made to name a node outside the body's skeleton: the Arms are left out with one warning
    line naming them and why; the body and the helmet load as before."""
    c = make_character(0.05, fps=FPS)
    path = write_game_humanoid(tmp_path / "two.gltf", c)
    doc = json.loads(path.read_text())
    doc["nodes"].append({"name": "Stray"})
    doc["scenes"][0]["nodes"].append(len(doc["nodes"]) - 1)
    doc["skins"][1]["joints"][0] = len(doc["nodes"]) - 1
    path.write_text(json.dumps(doc))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = load_gltf(path, fps=FPS)
    messages = [str(w.message) for w in caught if issubclass(w.category, PrtWarning)]
    assert any(m.startswith("two.gltf: 2 mesh node(s) not part of the character, left out: 'Arms' (skin 1 has joints "
                            "outside skin 0), 'Crate'") for m in messages), messages
    d, _ = cKDTree(c.rest_vertices).query(g.rest_vertices)
    assert (d >= 1e-4).sum() == 8  # the helmet, nothing else foreign
    assert (d < 1e-4).sum() < c.num_vertices  # the arm vertices are gone
