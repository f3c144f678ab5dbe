"""The scene's compiled SHEXP (prt_torch.scene.shexp_kernel) and compiled SH products (prt_torch.scene.compose).

References: the run's exported ``shexp.onnx`` in onnxruntime (a second implementation of the same numbers) and the
torch module it was exported from; the unculled compiled pass (``eps = 0``) for the culling, with the bound stated
in the module (``||V_culled - V||_2 <= B eps``); :func:`prt_torch.sh.product.sh_product` (dense Gaunt) and
:meth:`Composer.occluder` for the products; a brute-force point-in-capsule test for the floor under the feet.
"""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.scene.shexp_kernel import (
    CULL_SOLID_ANGLE,
    CompiledShexp,
    ShexpTables,
    log_norm_bound,
)
from tests.scene.fixtures import scene_run  # noqa: F401  (session fixture)
from tests.tolerance import assert_bitwise, two_path_atol


def _built(order: int) -> ShexpTables:
    """The tables as :mod:`prt_torch.shexp` builds them (torch: the log table's fit)."""
    from prt_torch.shexp.exponential import square_operators
    from prt_torch.shexp.tables import cos_log_table, ol_table

    to_p, from_p = square_operators(order)
    return ShexpTables(order, np.ascontiguousarray(cos_log_table(order), dtype=np.float32),
                       np.ascontiguousarray(ol_table(order), dtype=np.float32), to_p, from_p)


def _receivers(rng: np.random.Generator, v: int, s: int):
    pts = rng.normal(size=(v, 3)).astype(np.float32)
    q, _ = np.linalg.qr(rng.normal(size=(v, 3, 3)))
    frames = np.swapaxes(q, -1, -2)
    frames *= np.sign(np.linalg.det(frames))[:, None, None]  # proper rotations, rows (t, b, n)
    centers = (rng.normal(size=(s, 3)) * 1.5).astype(np.float32)
    radii = rng.uniform(0.1, 0.6, size=s).astype(np.float32)
    return pts, frames.astype(np.float32), centers, radii


def _graph_constants(path) -> ShexpTables:
    """The 2-D constants the graph computes with (read with ``onnx``, not through its metadata): shapes
    ``(N + 1, n)``, ``(N_OL, 2)``, ``(C, Q)``, ``(Q, C)``, in the main graph and the squaring loops."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(path))
    order = int({p.key: p.value for p in model.metadata_props}["order"])
    c = order * order
    found: dict[tuple[int, ...], np.ndarray] = {}

    def walk(graph) -> None:
        for node in graph.node:
            for a in node.attribute:
                if a.type == onnx.AttributeProto.GRAPH:
                    walk(a.g)
                elif node.op_type == "Constant" and a.type == onnx.AttributeProto.TENSOR and len(a.t.dims) == 2:
                    found.setdefault(tuple(a.t.dims), numpy_helper.to_array(a.t))
        for t in graph.initializer:
            if len(t.dims) == 2:
                found.setdefault(tuple(t.dims), numpy_helper.to_array(t))

    walk(model.graph)
    q = [k[1] for k in found if k[0] == c and (k[1], c) in found and k[1] != c]
    logs = sorted((k for k in found if k[1] == order), reverse=True)  # the log table: the longest (N + 1, n)
    ols = sorted((k for k in found if k[1] == 2 and k not in logs[:1]), reverse=True)
    assert len(q) == 1 and logs and ols and logs[0][0] > ols[0][0], sorted(found)
    return ShexpTables(order, found[logs[0]], found[ols[0]], found[(c, q[0])], found[(q[0], c)])


def test_tables_from_the_graph_are_the_built_ones(scene_run) -> None:  # noqa: F811
    from prt_torch.rundir import RunDir

    run = RunDir(scene_run)
    got = ShexpTables.from_graph(run.shexp_path)  # the metadata, through onnxruntime
    ref = _built(got.order)
    consts = _graph_constants(run.shexp_path)
    for name in ("table", "ol", "to_points", "from_points"):
        assert_bitwise(getattr(got, name), getattr(ref, name), why="the graph stores the float32 tables as built")
        assert_bitwise(getattr(got, name), getattr(consts, name), why="the metadata holds the graph's own constants")


def test_a_graph_without_its_tables_is_refused(scene_run, tmp_path) -> None:  # noqa: F811
    """An older export (no tables in the metadata) or damaged tables: one-line errors naming the re-export."""
    import onnx

    from prt_torch.errors import PrtError
    from prt_torch.rundir import RunDir
    from prt_torch.scene.shexp_kernel import TABLES_METADATA_KEY

    model = onnx.load(str(RunDir(scene_run).shexp_path))
    keep = [(p.key, p.value) for p in model.metadata_props if p.key != TABLES_METADATA_KEY]
    for name, extra in (("old", None), ("damaged", "{not json")):
        del model.metadata_props[:]
        for k, v in keep + ([(TABLES_METADATA_KEY, extra)] if extra else []):
            model.metadata_props.add(key=k, value=v)
        path = tmp_path / f"{name}.onnx"
        onnx.save(model, str(path))
        with pytest.raises(PrtError, match="re-export the run") as e:
            ShexpTables.from_graph(path)
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("world", [False, True])
def test_compiled_shexp_matches_onnxruntime_and_torch(scene_run, world) -> None:  # noqa: F811
    import torch

    from prt_torch.rundir import RunDir
    from prt_torch.scene.occluders import ShexpGraph
    from prt_torch.shexp import ShexpVisibility
    from prt_torch.shexp.graph import SHEXP_PARITY_RTOL

    run = RunDir(scene_run)
    tables = ShexpTables.from_graph(run.shexp_path)
    pts, frames, centers, radii = _receivers(np.random.default_rng(3), 700, 23)  # some receivers inside spheres
    fr = np.broadcast_to(np.eye(3, dtype=np.float32), frames.shape) if world else frames
    got = CompiledShexp(tables, pts, eps=0.0)(pts, None if world else frames, centers, radii)
    ort = ShexpGraph(run.shexp_path, tables.order, threads=1)(pts[None], np.ascontiguousarray(fr[None]),
                                                              centers[None], radii[None], cull=0)[0]
    ref = ShexpVisibility(tables.order)(*(torch.from_numpy(np.ascontiguousarray(x)[None]) for x in
                                          (pts, fr, centers, radii)))[0].numpy()
    scale = float(np.abs(ref).max())
    assert np.abs(got - ort).max() <= SHEXP_PARITY_RTOL * scale
    assert np.abs(got - ref).max() <= SHEXP_PARITY_RTOL * scale


def test_culled_crowd_equals_unculled_within_the_stated_bound(scene_run) -> None:  # noqa: F811
    """Three characters on a floor, every character's vertices under the others' spheres and the floor under all:
    culled (10x the default budget, so that the culling drops many pairs) vs every sphere at every receiver."""
    from prt_torch.blockers import pose_spheres
    from prt_torch.commands.bench_scene import grid_scene
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.rundir import RunDir
    from prt_torch.scene.scene import spheres_above

    run = RunDir(scene_run)
    ch = run.character()
    c = ch.clip("wave")
    sp = ScenePlayer(run, scene=grid_scene(ch, "wave", 3, c.num_frames / c.fps), threads=1, peaks=0)
    try:
        eps = 10 * CULL_SOLID_ANGLE
        tables = sp.shexp[0].tables
        bound = log_norm_bound(tables, eps) * eps
        states = [p.pose(a.locals(np.array([2]), sp.fps)) for a, p in zip(sp.actors, sp.actor_players, strict=True)]
        centers = [pose_spheres(a.spheres, s.skin)[0] for a, s in zip(sp.actors, states, strict=True)]
        radii = [np.asarray(a.spheres.radius, np.float32) for a in sp.actors]
        cases = []
        for k, (a, st) in enumerate(zip(sp.actors, states, strict=True)):
            oc = np.concatenate([x for j, x in enumerate(centers) if j != k])
            orad = np.concatenate([x for j, x in enumerate(radii) if j != k])
            cases.append((a.rest_vertices(), st.positions_vx3(0), st.frames_vx33()[0], oc, orad))
        gc, gr = spheres_above(np.concatenate(centers)[None], np.concatenate(radii)[None], sp.ground.height)
        cases.append((sp.ground.vertices, sp.ground.vertices, None, gc[0], gr[0]))
        dropped = 0
        for rest, pos, fr, oc, orad in cases:
            culled = CompiledShexp(tables, rest, eps=eps)
            full = CompiledShexp(tables, rest, eps=0.0)
            v_c, v_f = culled(pos, fr, oc, orad), full(pos, fr, oc, orad)
            assert np.linalg.norm(v_c - v_f, axis=1).max() <= bound
            outside = np.setdiff1d(np.arange(pos.shape[0]), culled.occluded)  # the constant 1 exactly
            assert_bitwise(v_c[outside, 1:], np.zeros_like(v_c[outside, 1:]), why="the constant 1 is written as such")
            dropped += full.stats["pairs"] - culled.stats["pairs"]
        assert dropped > 0
    finally:
        sp.close()


def test_a_floor_far_from_every_sphere_is_the_constant_one() -> None:
    tables = _built(3)
    g = np.stack(np.meshgrid(np.linspace(0, 40, 30), np.linspace(0, 40, 30), [0.0]), -1).reshape(-1, 3)
    sx = CompiledShexp(tables, g)
    centers = np.array([[1.0, 1.0, 0.5], [1.2, 1.0, 1.0]], np.float32)
    v = sx(g, None, centers, np.array([0.3, 0.2], np.float32))
    near = np.linalg.norm(g - [1.0, 1.0, 0.0], axis=1) < 2.0
    assert set(np.flatnonzero(near)) <= set(sx.occluded) and len(sx.occluded) < 0.5 * len(g)
    far = np.setdiff1d(np.arange(len(g)), sx.occluded)
    assert_bitwise(v[far], np.broadcast_to(v[far[0]], v[far].shape), why="the constant 1 is written as such")
    assert v[far[0], 0] == pytest.approx(np.sqrt(4 * np.pi)) and sx.stats["blocks"] < sx.stats["all_blocks"]


@pytest.mark.parametrize("below_horizon", ["zero", "one"])
def test_compiled_products_match_sh_product(below_horizon) -> None:
    from prt_torch.scene.compose import Composer, ground_products, halfspace_visibility, sh_products
    from prt_torch.sh.product import sh_product

    rng = np.random.default_rng(5)
    a = rng.normal(size=(2, 40, 16)).astype(np.float32)
    b = rng.normal(size=(2, 40, 16)).astype(np.float32)
    q, _ = np.linalg.qr(rng.normal(size=(2, 40, 3, 3)))
    frames = np.swapaxes(q, -1, -2).astype(np.float32)
    ref = sh_product(a.astype(np.float64), b.astype(np.float64))
    # each output a sum of at most 353 Gaunt terms (order 4), |Gamma| < 0.6: bounded by 0.6 sum|a| sum|b| per row
    atol = two_path_atol(400, 0.6 * float((np.abs(a).sum(-1) * np.abs(b).sum(-1)).max()))
    np.testing.assert_allclose(sh_products(a, b), ref, atol=atol)
    rows = np.array([1, 7, 55])
    part = sh_products(a, b, rows).reshape(-1, 16)
    np.testing.assert_allclose(part[rows], ref.reshape(-1, 16)[rows], atol=atol)
    assert_bitwise(np.delete(part, rows, 0), np.delete(a.reshape(-1, 16), rows, 0), why="rows left as a copy")
    comp = Composer(4, below_horizon)
    ref_g = sh_product(a.astype(np.float64), comp.occluder(halfspace_visibility(frames, 4)).astype(np.float64))
    h = np.abs(comp.occluder(halfspace_visibility(frames, 4))).sum(-1)
    atol_g = two_path_atol(400, 0.6 * float((np.abs(a).sum(-1) * h).max()))
    np.testing.assert_allclose(ground_products(a, frames, below_horizon), ref_g, atol=atol_g)
    others = rng.normal(size=(2, 40, 16)).astype(np.float32)
    ref_s = sh_product(ref_g, comp.occluder(others).astype(np.float64))
    o = np.abs(comp.occluder(others)).sum(-1)
    atol_s = two_path_atol(800, 0.6 * float((np.abs(ref_g).sum(-1) * o).max())) + 0.6 * float(o.max()) * atol_g * 16
    np.testing.assert_allclose(comp.in_scene(a, frames, ground=True, others=others), ref_s, atol=atol_s)


def test_inside_capsules_is_the_brute_force_test() -> None:
    from prt_torch.scene.peaks import inside_capsules

    rng = np.random.default_rng(2)
    p = rng.uniform(-1, 1, size=(2000, 3))
    a = rng.uniform(-1, 1, size=(9, 3))
    b = a + rng.normal(scale=0.3, size=(9, 3))
    b[:3] = a[:3]  # spheres
    r = rng.uniform(0.05, 0.3, size=9)
    w = b - a
    t = np.clip(((p[:, None] - a[None]) * w[None]).sum(-1) / np.maximum((w * w).sum(-1), 1e-300), 0, 1)
    q = p[:, None] - a[None] - t[..., None] * w[None]
    ref = ((q * q).sum(-1) < r ** 2).any(-1)
    assert ref.any() and not ref.all()
    np.testing.assert_array_equal(inside_capsules(p, a, b, r), ref)
    assert not inside_capsules(p, a[:0], b[:0], r[:0]).any()
