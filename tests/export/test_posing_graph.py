"""The posing path as an ONNX graph (onnxruntime) against the player's numpy Poser, on the tiny run's held-out
poses: positions, normals, frames, view directions, pose features; and the chained posing + fused graph against
the Poser followed by the run's fused graph.

Tolerances: the Poser runs FK in float64, the graph in float32 throughout; positions / normals / view directions
agree to ``atol 2e-5`` (unit vectors and a ~2 m character), frames to ``atol 1e-4`` (the tangent's projection
divides by ``|t_a|``, which can be ~0.1), features to ``atol 1e-6``; radiance to ``rtol 1e-4`` of its maximum.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.export.posing_graph import (
    POSING_OUTPUTS,
    PosingGraph,
    chain_posing_fused,
    export_posing_graph,
)
from prt_torch.player import Player
from prt_torch.runtime.session import OrtGraph


@pytest.fixture(scope="module")
def posing(tiny_run: Path, tmp_path_factory: pytest.TempPathFactory):
    player = Player(tiny_run, graph="fused", brdf="phong", threads=1)
    b = player.bundle
    graph = PosingGraph(player.character, b.cluster, b.cluster_axis, b.cluster_bone, order=player.vertex_order)
    path = export_posing_graph(graph, tmp_path_factory.mktemp("posing") / "posing.onnx")
    yield player, path
    player.close()


def _heldout_locals(player: Player) -> np.ndarray:
    loc = player.clip_locals("wave")  # the tiny config's held-out clip
    idx = np.linspace(0, len(loc) - 1, 5).round().astype(int)
    return np.ascontiguousarray(loc[idx], dtype=np.float32)


def test_posing_onnx_equals_numpy_poser(posing) -> None:
    player, path = posing
    g = OrtGraph(path, threads=1)
    loc = _heldout_locals(player)
    for eye in (player.eye, np.array([0.4, -3.0, 2.5])):
        ref = player.poser(loc, eye)
        out = g.run({"local": loc, "eye": np.asarray(eye, np.float32)})
        assert set(out) == set(POSING_OUTPUTS)
        o = player.vertex_order
        for name, atol in (("positions", 2e-5), ("normals", 2e-5), ("view_dirs", 2e-5), ("frames", 1e-4)):
            np.testing.assert_allclose(out[name], ref.in_order(name, o), rtol=0, atol=atol, err_msg=name)
        np.testing.assert_allclose(out["features"], ref.features, rtol=0, atol=1e-6)
    # the batch axis is dynamic: one pose alone gives the same rows
    one = g.run({"local": loc[2:3], "eye": np.asarray(player.eye, np.float32)})
    np.testing.assert_allclose(one["frames"][0], g.run({"local": loc, "eye": np.asarray(player.eye, np.float32)})
                               ["frames"][2], atol=1e-6)


def test_chained_posing_fused_equals_poser_then_fused(posing, tmp_path: Path) -> None:
    player, path = posing
    chained = OrtGraph(chain_posing_fused(path, player.bundle.graphs["fused"].path, tmp_path / "chained.onnx"),
                       threads=1)
    loc = _heldout_locals(player)
    state = player.pose(loc)
    feeds = player._fused_feeds(state)
    want = player.bundle.graphs["fused"].run(feeds)["radiance"]
    rest = {k: v for k, v in feeds.items() if k not in ("pose", "frames", "view_dirs")}
    got = chained.run({"posing/local": loc, "posing/eye": np.asarray(player.eye, np.float32), **rest})["radiance"]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * float(np.abs(want).max()))


def test_bad_cluster_data_is_refused(posing) -> None:
    player, _ = posing
    b = player.bundle
    with pytest.raises(PrtError, match="cluster labels"):
        PosingGraph(player.character, b.cluster[:-1], b.cluster_axis, b.cluster_bone)
    with pytest.raises(PrtError, match="permutation"):
        PosingGraph(player.character, b.cluster, b.cluster_axis, b.cluster_bone, order=np.zeros(len(b.cluster), int))
