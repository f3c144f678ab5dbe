"""The compiled CPU frame path (prt_torch.player.compiled) against onnxruntime's fused graph, the numpy poser and
the RPO's dense form; it is the player's default on the CPU."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.export.run import PARITY_RTOL_BY_PRECISION
from prt_torch.player import Player
from prt_torch.player.bundle import RPOTensors
from prt_torch.player.compiled import CompiledPoser, k_major, tiles
from prt_torch.player.posing import Poser
from tests.tolerance import assert_bitwise, two_path_atol


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.fixture(scope="module")
def players(tiny_run: Path) -> tuple[Player, Player]:
    comp, fused = Player(tiny_run, brdf="phong", peaks=0), Player(tiny_run, brdf="phong", peaks=0, graph="fused")
    yield comp, fused
    comp.close()
    fused.close()


def test_default_graph_is_compiled_on_the_cpu(players: tuple[Player, Player]) -> None:
    comp, _ = players
    assert comp.graph == "compiled" and comp.compiled is not None
    assert isinstance(comp.poser, CompiledPoser)


@pytest.mark.parametrize("brdf", ["phong", "lambert", "ggx", "ward"])
def test_compiled_radiance_equals_onnxruntime_fused(players: tuple[Player, Player], brdf: str) -> None:
    """A crowd of 3 different poses, every catalogue BRDF, a turned light: the compiled pass returns what fused.onnx
    returns (both in the original vertex order) within the export's parity tolerance of its precision."""
    comp, fused = players
    comp.set_brdf(brdf)
    fused.set_brdf(brdf)
    comp.rotate_light(0.7)
    fused.rotate_light(0.7)
    try:
        loc = comp.crowd_locals(["wave", "walk", "squat"], 2, stagger=1)
        state = fused.pose(loc)  # the same posed inputs for both paths
        want = fused.shade(state)
        got = comp.shade(state)
        tol = PARITY_RTOL_BY_PRECISION[comp.bundle.precision]
        assert got.shape == want.shape == (3, comp.bundle.n_vertices, 3)
        assert _rel(got, want) <= tol
        for i in range(3):  # a character of the crowd shades as it does alone
            assert _rel(comp.shade(fused.pose(loc[i:i + 1]))[0], got[i]) <= tol
    finally:
        comp.rotate_light(-0.7)
        fused.rotate_light(-0.7)


def test_compiled_poser_equals_the_numpy_poser(players: tuple[Player, Player]) -> None:
    """LBS from the non-zero weights, frames, view directions, FK and features in compiled passes: the numpy poser's
    numbers within float32 rounding (frames: the tangent's normalisation divides by lengths near the fallback)."""
    comp, _ = players
    ch, b = comp.character, comp.bundle
    ref = Poser(ch, b.cluster, b.cluster_axis, b.cluster_bone, order=comp.vertex_order)
    loc = comp.crowd_locals(["wave", "walk"], 1, stagger=2)
    got, want = comp.poser(loc, comp.eye), ref(loc, comp.eye)
    j = ch.num_joints
    # float32 LBS: the numpy path sums all J weights' products (a GEMM), the compiled one the non-zero ones; then
    # about 16 roundings of normalisation and cross products on unit-size values
    scale = max(1.0, float(np.abs(want.positions).max()))
    atol = two_path_atol(j + 16, scale)
    for name in ("positions", "normals", "view_dirs"):
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=atol, err_msg=name)
    # the tangent's normalisation divides by its blended length (>= ~0.1 away from the measure-zero degenerate case)
    np.testing.assert_allclose(got.frames, want.frames, atol=10 * atol)
    # FK + skinning in float64: 4-term products per entry, J levels deep at most
    np.testing.assert_allclose(got.skin, want.skin, atol=two_path_atol(4 * j, float(np.abs(want.skin).max()),
                                                                       np.float64))
    np.testing.assert_allclose(got.features, want.features, atol=two_path_atol(8, 1.0))


def test_compiled_poser_refuses_bad_locals(players: tuple[Player, Player]) -> None:
    comp, _ = players
    loc = comp.clip_locals("wave")[:1].copy()
    bad = loc.copy()
    bad[0, 1, :3, 0] = 0.0  # a zero-scale column: no rotation to extract
    with pytest.raises(PrtError, match="zero scale"):
        comp.poser(bad, comp.eye)
    nan = loc.copy()
    nan[0, 0, 0, 3] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        comp.poser(nan, comp.eye)


def test_rpo_not_in_product_form_is_refused(players: tuple[Player, Player]) -> None:
    comp, _ = players
    r = comp.rpo
    bent = RPOTensors(r.name, r.order, r.M * 1.01, r.w, r.tint, r.u)  # M no longer the product matrix of u
    with pytest.raises(PrtError, match="not the product matrix"):
        comp.compiled.rpo_tables(bent)


def test_tiles_cover_each_group_once() -> None:
    starts, n_used = np.array([0, 5, 5, 300]), np.array([5, 0, 295, 1])
    s, e, g = tiles(starts, n_used, 64)
    assert np.all(e - s >= 1) and np.all(e - s <= 64)
    for grp in range(4):
        cover = np.concatenate([np.arange(a, b) for a, b in zip(s[g == grp], e[g == grp], strict=True)]) \
            if (g == grp).any() else np.zeros(0, int)
        np.testing.assert_array_equal(cover, np.arange(starts[grp], starts[grp] + n_used[grp]))


def test_k_major_is_the_transposed_onnx_layout() -> None:
    """decode.npz stores each int8 basis as the ONNX lowering does (column, block, row); the kernel's k-major copy is
    the same numbers transposed (an independent dequantisation of both layouts)."""
    from prt_torch.export.graphs import int8_dequantize, int8_quantize

    rng = np.random.default_rng(0)
    c, ks, ns = 4, [5, 20], [3, 7]
    q_parts, s_parts, q_off, s_off, blocks, dense = [], [], [], [], [], []
    for k, n in zip(ks, ns, strict=True):
        w = rng.standard_normal((k, c * n)).astype(np.float32)
        q, s, blk = int8_quantize(w)
        q_off.append(sum(p.size for p in q_parts))
        s_off.append(sum(p.size for p in s_parts))
        q_parts.append(q.reshape(-1))
        s_parts.append(s.reshape(-1))
        blocks.append(blk)
        dense.append(int8_dequantize(q, s, k))
    d = {"q": np.concatenate(q_parts), "scales": np.concatenate(s_parts), "q_offsets": np.array(q_off),
         "scale_offsets": np.array(s_off), "n_used": np.array(ns), "k_used": np.array(ks), "blocks": np.array(blocks)}
    qk, sk, qo, so = k_major(d, c)
    for g, (k, n) in enumerate(zip(ks, ns, strict=True)):
        blk = blocks[g]
        nb = -(-k // blk)
        q = qk[qo[g]:qo[g] + k * c * n].reshape(k, c * n).astype(np.float32)
        s = sk[so[g]:so[g] + nb * c * n].reshape(nb, c * n)
        w = q * s[np.arange(k) // blk]
        assert_bitwise(w, dense[g], why="the same int8 value times the same float32 scale, one rounding each")


def test_run_without_compiled_data_plays_fused(tiny_run: Path, tmp_path: Path) -> None:
    """An export without the compiled entry (an older export) plays the fused graph by default; asking for
    ``compiled`` is a one-line error naming the fix."""
    from tests.export.pipeline import copy_run

    run = copy_run(tiny_run, tmp_path / "run")
    meta_path = run / "export.json"
    meta = json.loads(meta_path.read_text())
    meta.pop("compiled")
    meta_path.write_text(json.dumps(meta))
    shutil.rmtree(run / "models", ignore_errors=True)  # a player bundle: no model file to be stale against
    (run / "model.pt").unlink(missing_ok=True)
    p = Player(run, peaks=0)
    try:
        assert p.graph == "fused" and p.compiled is None
    finally:
        p.close()
    with pytest.raises(PrtError, match="no compiled frame path"):
        Player(run, peaks=0, graph="compiled")
