"""The deformable export (prt_torch.cloth.export): the positions-in graph and the deform data of a cloth run."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from tests.player.deformable_run import build_deformable_run, flag_mesh, heldout_positions
from tests.tolerance import assert_bitwise


@pytest.fixture(scope="session")
def deformable_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    return build_deformable_run(tmp_path_factory.getbasetemp())


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(np.asarray(a, np.float64) - b).max() / np.abs(b).max())


def test_positions_graph_matches_numpy_features_and_torch_model(deformable_run) -> None:
    """ORT positions.onnx(positions) == ORT visibility.onnx(numpy cloth_features(positions)) (the dihedral angles
    in the graph are the numpy rule), and == the torch model on those features up to the int8 bases' rounding."""
    import torch

    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.rundir import RunDir
    from prt_torch.runtime.session import OrtGraph

    run_dir, spec = deformable_run
    run = RunDir(run_dir)
    meta = run.export_meta()
    assert meta["deformable"]["inputs"] == ["positions"] and meta["deformable"]["n_edges"] == spec.edges.shape[0]
    pos = heldout_positions()[::3]
    feats = np.asarray(cloth_features(pos, spec.edges, None), np.float32)
    got = OrtGraph(run.positions_graph_path).run({"positions": pos})["visibility"]
    via_pose = OrtGraph(run.graph_path("visibility")).run({"pose": feats})["visibility"]
    assert _rel(got, via_pose) < 1e-4
    with torch.no_grad():
        ref = run.model(meta["model_kind"])(torch.from_numpy(feats)).numpy()
    assert got.shape == ref.shape == (len(pos), spec.operator.n_vertices, 9)
    assert _rel(got, ref) < 0.02  # int8 bases: well under one per cent in practice


def test_vertex_last_dihedral_graph_is_the_numpy_rule() -> None:
    """The exported pre-processing (one gather, rewritten with vector identities) == deform.dihedral_angles on a
    strongly folded random sheet, rigidly moved, in float32, including sharp folds near +-pi."""
    import torch

    from prt_torch.cloth.export import position_features_module
    from prt_torch.deform.dihedral import dihedral_angles
    from prt_torch.deform.mesh import interior_edges

    rest, faces = flag_mesh(9, 7)
    edges = interior_edges(faces)
    rng = np.random.default_rng(3)
    pos = rest[None] + rng.normal(scale=0.12, size=(4,) + rest.shape)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pos[1] = pos[0] @ q.T + 5.0  # a rigid motion of frame 0 (rotation/reflection + translation)
    pos = pos.astype(np.float32)
    ref = dihedral_angles(pos.astype(np.float64), edges)
    assert np.abs(ref).max() > 2.5  # sharp folds are part of the check
    with torch.no_grad():
        got = position_features_module(edges, 0)(torch.from_numpy(pos)).numpy()
    wrapped = np.angle(np.exp(1j * (got - ref)))  # +-pi are the same fold
    assert np.abs(wrapped).max() < 1e-4


def test_deform_data_round_trip_gives_the_bake_frames(deformable_run) -> None:
    """The shipped frame operator (deform.npz) gives exactly the frames of one rebuilt from the rest mesh."""
    from prt_torch.cloth.deform_data import DeformData
    from prt_torch.deform.frames import FrameOperator
    from prt_torch.rundir import RunDir

    run_dir, spec = deformable_run
    run = RunDir(run_dir)
    d = DeformData.load(run.deform_path)
    rest, faces = flag_mesh()
    ref = FrameOperator.from_rest(rest, faces, np.asarray(run.dataset().cluster))
    pos = heldout_positions()[:4]
    assert_bitwise(d.operator.frames(pos), ref.frames(pos),
                   why='the same operator data (round trip) and the same operations')
    np.testing.assert_array_equal(d.edges, spec.edges)
    assert d.cloth_slice == slice(0, rest.shape[0]) and d.n_body_features == 0


def test_tampered_positions_graph_is_refused(deformable_run, tmp_path: Path) -> None:
    from prt_torch.cloth.player import DeformablePlayer

    run_dir, _ = deformable_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    g = copy / "positions.onnx"
    g.write_bytes(g.read_bytes()[:-8] + b"\0" * 8)
    with pytest.raises(PrtError, match="positions.onnx") as exc:
        DeformablePlayer(copy)
    assert "\n" not in str(exc.value)


def test_wrong_cloth_edges_are_refused(deformable_run, tmp_path: Path) -> None:
    """A spec whose edges do not reproduce the dataset's pose column fails the export with one line."""
    from dataclasses import replace

    from prt_torch.export.run import export_run

    run_dir, spec = deformable_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    bad = replace(spec, edges=spec.edges[::-1].copy())  # the same edges in another order: columns permuted
    with pytest.raises(PrtError, match="pose column") as exc:
        export_run(copy, brdfs=("lambert",), deform=bad, force=True)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("method", ["learned_mlp", "learned_linear"])
def test_compare_learned_methods_run_the_positions_graph(deformable_run, method: str) -> None:
    """prt compare's learned methods on a deformable run take POSITIONS (the shipped positions.onnx for the exported
    kind, one exported by compare for another kind) and give the visibility of the model on cloth_features."""
    import torch

    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.compare.methods import METHODS, CompareRun, FrameBatch
    from prt_torch.rundir import RunDir

    run_dir, spec = deformable_run
    run = RunDir(run_dir)
    ctx = CompareRun(run=run, dataset=run.dataset(), character=run.character(), order=run.dataset().order, bake={},
                     model_meta=run.model_meta(), export_meta=run.export_meta())
    m = METHODS[method]()
    assert type(m).available(ctx)
    m.prepare(ctx, None)
    assert m.info()["input"] == "positions"
    assert m.source == ("shipped" if method == "learned_mlp" else "exported by prt compare")
    pos = heldout_positions()[::6]
    feats = np.asarray(cloth_features(pos, spec.edges, None), np.float32)
    got = m.visibility(FrameBatch(index=np.arange(len(pos)), features=np.full_like(feats, np.nan), positions=pos,
                                  frames=np.zeros(pos.shape + (3,), np.float32)))
    with torch.no_grad():
        ref = run.model(method.removeprefix("learned_"))(torch.from_numpy(feats)).numpy()
    assert _rel(got, ref) < 0.02
