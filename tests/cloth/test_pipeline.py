"""The deformable (cloth) branch of the pipeline, issue 11: vertex cache -> plan -> bake -> train -> compare.

Independent references: the occluded solid angle of a folded sheet (closed form: an infinite fold of opening
angle alpha leaves a lune of solid angle 2 alpha open) and direct ray casts (a plain-numpy Moller-Trumbore
intersector, not Embree); the panels' normals in closed form; bitwise equality of an interrupted-then-resumed
bake with an uninterrupted one. The end-to-end test runs the real MuJoCo simulation of a tiny cape (300 cloth
vertices on the ~600-vertex body) through the CLI's own entry point: prt bake (simulates) -> train -> compare.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from prt_torch.bake.store import BakedDataset
from prt_torch.cloth.bake import make_deformable_plan
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from prt_torch.rundir import RunDir
from tests.raycast import rays_hit
from tests.tolerance import assert_bitwise, two_path_atol

Y00 = 0.5 / np.sqrt(np.pi)
NU, NW = 25, 13  # fold sheet grid: NU across the fold (u in [-1, 1]), NW along it (w in [-1.5, 1.5])
ALPHAS = (np.pi, 0.75 * np.pi, 0.5 * np.pi, 0.3 * np.pi)  # opening angles of the fold's 4 frames


def fold_positions(alpha: float) -> np.ndarray:
    """``(NU * NW, 3)`` sheet folded about the y axis: panel A (u >= 0) along +x, panel B (u < 0) at angle
    ``alpha`` from A (``alpha = pi``: flat, normal +z); the fold's inside faces +z of panel A."""
    u, w = np.meshgrid(np.linspace(-1.0, 1.0, NU), np.linspace(-1.5, 1.5, NW), indexing="ij")
    d = np.abs(u)
    dx = np.where(u >= 0, 1.0, np.cos(alpha))
    dz = np.where(u >= 0, 0.0, np.sin(alpha))
    return np.stack([d * dx, w, d * dz], axis=-1).reshape(-1, 3).astype(np.float32)


def grid_faces() -> np.ndarray:
    idx = np.arange(NU * NW).reshape(NU, NW)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def sheet_character(rest: np.ndarray, faces: np.ndarray) -> Character:
    """A single-root-joint character (every weight 1 on it), as a cloth subject is saved."""
    from prt_torch.rig.mesh import vertex_normals

    v = len(rest)
    eye = np.eye(4)[None]
    return Character(name="fold", joint_names=["root"], parents=np.array([-1]), bind_local=eye, inverse_bind=eye,
                     rest_vertices=rest, rest_normals=vertex_normals(rest, faces), faces=faces,
                     joints=np.zeros((v, 1), np.int64), weights=np.ones((v, 1), np.float32))


@dataclass
class FakeSubject:
    """The :class:`prt_torch.cloth.subject.ClothSubject` surface the plan uses, for an analytic sheet."""

    character: Character
    cloth_edges: np.ndarray
    train: list[str]
    heldout: list[str]

    def sequences(self, split: str) -> list[str]:
        return list(self.train if split == "train" else self.heldout)


class FakeCache:
    """The :class:`prt_torch.cloth.cache.VertexCache` surface the plan uses."""

    def __init__(self, seqs: dict[str, np.ndarray]) -> None:
        self.seqs = seqs

    def sequences(self) -> list[str]:
        return list(self.seqs)

    def positions(self, name: str) -> np.ndarray:
        return self.seqs[name]

    def body_features(self, name: str) -> None:
        return None


def fold_setup(tmp_path: Path, order: int = 3, n_rays: int = 256, frames_per_task: int = 2,
               below: str = "zero") -> tuple[Any, FakeSubject, FakeCache]:
    from prt_torch.deform.mesh import interior_edges

    faces = grid_faces()
    rest = fold_positions(np.pi)
    subject = FakeSubject(sheet_character(rest, faces), interior_edges(faces), ["fold"], ["unfold"])
    fold = np.stack([fold_positions(a) for a in ALPHAS])
    cache = FakeCache({"fold": fold, "unfold": fold[::-1].copy()})
    cfg = config_from_dict({"name": "fold", "run_dir": str(tmp_path / "fold"), "character": {},
                            "bake": {"order": order, "n_rays": n_rays, "frames_per_task": frames_per_task,
                                     "below_horizon": below, "max_clusters": 6, "ray_offset": 1e-4}})
    return cfg, subject, cache


def bake_plan(cfg: Any, plan: Any, on_block: Any = None) -> Any:
    """The bake of a given plan, in process (run_bake without its make_plan)."""
    from prt_torch.bake import runner

    with RunDir(cfg.out_dir.resolve()).lock("bake"):
        return runner._run_bake(cfg, plan, 1, None, False, on_block)


@pytest.fixture(scope="module")
def fold_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Any, Path]:
    cfg, subject, cache = fold_setup(tmp_path_factory.mktemp("fold"))
    plan = make_deformable_plan(cfg, subject, cache)
    return cfg, plan, bake_plan(cfg, plan).path


def test_plan_of_a_cache(fold_run: tuple[Any, Any, Path]) -> None:
    _, plan, path = fold_run
    ds = BakedDataset(path)
    assert ds.complete and ds.attrs["deformable"] is True and ds.clip_names == ["fold", "unfold"]
    assert ds.splits == {"train": ["fold"], "heldout": ["unfold"]}
    np.testing.assert_array_equal(ds.frame_index, [0, 1, 2, 3, 0, 1, 2, 3])
    assert_bitwise(ds.positions, plan.positions, why="the bake traces the cached positions as they are (a copy)")
    # pose = signed dihedral angles of the interior edges: the fold edges carry pi - alpha (sign by convention)
    fold_edges = np.abs(ds.pose[:4]).max(axis=1)
    np.testing.assert_allclose(fold_edges, np.pi - np.array(ALPHAS), atol=1e-4)


def test_fold_visibility_vs_closed_form_and_direct_rays(fold_run: tuple[Any, Any, Path]) -> None:
    """Panel A vertices 2..4 grid steps from the fold, mid-sheet: the baked DC coefficient is the open solid
    angle x Y00; an infinite fold leaves 2 alpha open (finite panels a little more); direct ray casts with
    Moller-Trumbore (independent of Embree and of the bake's rays) on the same triangles agree within MC noise."""
    _, plan, path = fold_run
    ds = BakedDataset(path)
    faces = np.asarray(ds.faces)
    u_idx = np.array([NU // 2 + 2, NU // 2 + 4])
    verts = (u_idx[:, None] * NW + np.array([NW // 2 - 1, NW // 2 + 1])[None]).ravel()
    rng = np.random.default_rng(1)
    n_ref = 2048
    for f, alpha in enumerate(ALPHAS):
        pos = ds.positions[f].astype(np.float64)
        frames = ds.frames[f]
        np.testing.assert_allclose(frames[verts, 2], np.tile([0.0, 0.0, 1.0], (len(verts), 1)), atol=1e-5)
        open_baked = ds.visibility[f][verts, 0] / Y00
        # direct rays: uniform over the upper hemisphere (panel A's normal is +z), numpy Moller-Trumbore
        d = rng.normal(size=(n_ref, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d[:, 2] = np.abs(d[:, 2])
        tri = pos[faces]
        for v, ob in zip(verts, open_baked, strict=True):
            hit = rays_hit(pos[v] + [0, 0, 1e-4], d, tri).any(axis=1)
            open_ref = 2 * np.pi * (1.0 - hit.mean())
            assert abs(ob - open_ref) < 0.25, (f, v, ob, open_ref)  # 256 bake rays vs 2048: ~3 sigma
            assert 2 * alpha - 0.1 < ob < 2 * alpha + 0.9, (f, v, ob, 2 * alpha)  # finite panels leak a little
        if f == 0:  # flat: nothing occludes
            np.testing.assert_allclose(open_baked, 2 * np.pi, atol=1e-3)


def test_frames_equal_the_frame_operator_on_the_cache(fold_run: tuple[Any, Any, Path]) -> None:
    from prt_torch.deform.frames import FrameOperator

    _, plan, path = fold_run
    ds = BakedDataset(path)
    ch = RunDir(path.parent).character()
    op = FrameOperator.from_rest(ch.rest_vertices, ch.faces, ds.cluster)
    np.testing.assert_allclose(ds.frames, op.frames(plan.positions), atol=1e-6)
    np.testing.assert_allclose(ds.normals, ds.frames[:, :, 2], atol=1e-6)
    f = ds.frames.astype(np.float64)
    np.testing.assert_allclose(f @ np.swapaxes(f, -1, -2), np.broadcast_to(np.eye(3), f.shape), atol=1e-4)
    # panel B's normal in closed form: the +z normal turned with the panel, (sin a, 0, -cos a) for opening a
    b_verts = (np.arange(0, NU // 2 - 2)[:, None] * NW + np.arange(1, NW - 1)[None]).ravel()
    for fi, alpha in enumerate(ALPHAS):
        np.testing.assert_allclose(ds.frames[fi][b_verts, 2], np.tile([np.sin(alpha), 0, -np.cos(alpha)],
                                                                      (len(b_verts), 1)), atol=1e-5)


class _Stop(Exception):
    pass


def test_interrupted_deformable_bake_resumes_bitwise(tmp_path: Path, fold_run: tuple[Any, Any, Path]) -> None:
    cfg, subject, cache = fold_setup(tmp_path)
    plan = make_deformable_plan(cfg, subject, cache)
    seen = []

    def stop(_: Any) -> None:
        seen.append(1)
        if len(seen) == 2:
            raise _Stop

    with pytest.raises(_Stop):
        bake_plan(cfg, plan, stop)
    assert 0 < BakedDataset(cfg.out_dir / "dataset.zarr").done.sum() < plan.n_frames
    res = bake_plan(cfg, plan)
    assert res.skipped == 4 and res.frames == plan.n_frames - 4
    ref = BakedDataset(fold_run[2])
    ds = BakedDataset(res.path)
    for name in ("visibility", "frames", "positions", "normals", "pose", "cluster"):
        assert_bitwise(np.asarray(ds.array(name)[:]), np.asarray(ref.array(name)[:]), err_msg=name,
                       why="the bake is bit-exact: a resumed bake equals an uninterrupted one")


def test_bad_caches_are_one_line_errors(tmp_path: Path) -> None:
    cfg, subject, cache = fold_setup(tmp_path)
    bad = FakeCache({k: v.copy() for k, v in cache.seqs.items()})
    bad.seqs["unfold"][2, 17, 1] = np.nan
    with pytest.raises(PrtError, match=r"^vertex cache sequence 'unfold': NaN or Inf positions in 1 frame\(s\) "
                                       r"\(first: frame 2\)") as e:
        make_deformable_plan(cfg, subject, bad)
    assert "\n" not in str(e.value)
    short = FakeCache({k: v[:, :-3] for k, v in cache.seqs.items()})
    with pytest.raises(PrtError, match=r"322 vertices per frame, the subject has 325") as e:
        make_deformable_plan(cfg, subject, short)
    assert "\n" not in str(e.value)
    gone = FakeCache({"fold": cache.seqs["fold"]})
    with pytest.raises(PrtError, match=r"sequence 'unfold' is not in the vertex cache") as e:
        make_deformable_plan(cfg, subject, gone)
    assert "\n" not in str(e.value)


# -- the real path: MuJoCo cape -> prt bake -> prt train -> prt compare ------------------------------------------

TINY_CAPE = {
    "name": "cape_tiny",
    "character": {"source": "builtin", "density": 0.05, "fps": 10.0,
                  "train_clips": [{"clip": "walk", "frames": "0:5"}, {"clip": "squat", "frames": "0:5"}],
                  "heldout_clips": [{"clip": "wave", "frames": "0:4"}]},
    "cloth": {"scene": "cape", "rows": 20, "cols": 15, "settle_frames": 2, "substeps": 32},
    "bake": {"order": 3, "n_rays": 64, "frames_per_task": 4, "max_clusters": 8, "workers": 1},
    "train": {"kinds": ["linear", "mlp"], "input_selection": "pca", "input_variance": 0.9, "folds": 2,
              "alphas": [0.01, 1.0], "mlp_alphas": [1.0], "neurons": [4], "cv_iter": 20, "max_iter": 40,
              "device": "cpu",
              "local": {"radii": [0.05, 0.15], "angles": 4, "hidden": [8], "steps": 300, "batch": 512, "lr": 3e-3,
                        "default": "mlp"}},
}


def prt(*args: str) -> tuple[int, str]:
    """``prt ARGS`` in this process (the CLI's own entry point); returns (exit code, stderr)."""
    import contextlib
    import io

    from prt_torch.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(list(args))
    return code, err.getvalue()


@pytest.fixture(scope="module")
def cape_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("mujoco")
    root = tmp_path_factory.mktemp("cape")
    cfg_path = root / "cape_tiny.yaml"
    cfg_path.write_text(yaml.safe_dump(TINY_CAPE))
    run = root / "run"
    code, err = prt("bake", str(cfg_path), "--run-dir", str(run), "--no-progress")
    assert code == 0, err
    code, err = prt("train", str(cfg_path), "--run-dir", str(run))
    assert code == 0, err
    return run


def test_cape_simulate_bake_train_compare(cape_run: Path) -> None:
    from prt_torch.cloth.cache import VertexCache
    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.cloth.subject import ClothSubject

    run = RunDir(cape_run)
    ds = run.dataset()
    cfg = config_from_dict({**TINY_CAPE, "run_dir": str(cape_run)})
    subject = ClothSubject.load(cfg)
    cache = VertexCache(run.simulation)
    assert ds.complete and ds.attrs["deformable"] is True
    assert ds.splits == {"train": subject.sequences("train"), "heldout": subject.sequences("heldout")}
    for name in ds.clip_names:  # the dataset traced the cache's positions; pose = the cloth's dihedral angles
        rows = ds.clip_rows(name)
        assert_bitwise(ds.rows(rows, ("positions",))["positions"], cache.positions(name),
                       why="the dataset stores the cache's positions as they are (a copy)")
        np.testing.assert_allclose(ds.pose[rows], cloth_features(cache.positions(name), subject.cloth_edges, None),
                                   atol=1e-6)
    assert ds.n_vertices == subject.character.num_vertices == run.character().num_vertices
    learned = ("learned_linear", "learned_mlp", "learned_local_linear", "learned_local_mlp")
    code, err = prt("compare", str(cape_run), "--methods", ",".join(learned), "--image-frames", "2",
                    "--reference-frames", "0", "--frames", "3")
    assert code == 0, err
    res = json.loads(run.compare_json.read_text())
    assert {n for n in res["methods"] if "+peaks_" not in n} == {"sh_truth", *learned}
    assert res["clips"] == subject.sequences("heldout") and res["frames"] == 3
    truth_err = res["methods"]["sh_truth"]["vis_rel_err"]
    assert truth_err == 0.0
    # the local models (train.local): onnxruntime on the offsets (numba) gives the torch model's visibility
    metrics = json.loads(run.metrics_json.read_text())
    assert set(metrics["local"]) == {"linear", "mlp"}
    for m in learned:  # real predictions: better than nothing, not the truth itself
        assert 0.0 < res["methods"][m]["vis_rel_err"] < 0.5
        assert res["methods"][m]["psnr_image_diffuse"] > 20.0
    # --clip NAME of a deformable run: the cached sequence, frames by the bake's rule, equal to the dataset's rows
    from prt_torch.compare.run import deformable_clip_frames, heldout_frames, load_compare_run

    ctx = load_compare_run(cape_run)
    name = subject.sequences("heldout")[0]
    a, b = deformable_clip_frames(ctx, name), heldout_frames(ctx)
    assert_bitwise(a.positions, b.positions, why='both read the same dataset rows')
    np.testing.assert_allclose(a.frames, b.frames, atol=1e-6)
    np.testing.assert_allclose(a.features, b.features, atol=1e-6)


def test_body_visibility_sees_the_cape(cape_run: Path) -> None:
    """Body vertices behind the cape: direct ray casts (Moller-Trumbore) against the body alone and against body +
    cape differ there; the baked visibility follows body + cape (the bake sees the cloth as an occluder)."""
    from prt_torch.cloth.subject import ClothSubject

    run = RunDir(cape_run)
    ds = run.dataset()
    cfg = config_from_dict({**TINY_CAPE, "run_dir": str(cape_run)})
    subject = ClothSubject.load(cfg)
    faces = np.asarray(ds.faces)
    nb = subject.cloth_slice.start
    is_body = (faces < nb).all(axis=1)
    f = int(ds.split_rows("heldout")[0])
    pos = ds.positions[f].astype(np.float64)
    frames = ds.frames[f].astype(np.float64)
    rng = np.random.default_rng(3)
    # body vertices facing backwards (toward the cape), a sample of them
    back = np.flatnonzero(frames[:nb, 2, 1] > 0.5)
    verts = rng.choice(back, size=min(16, len(back)), replace=False)
    d_local = rng.normal(size=(512, 3))
    d_local /= np.linalg.norm(d_local, axis=1, keepdims=True)
    d_local[:, 2] = np.abs(d_local[:, 2])
    offset = float(ds.attrs["bake"]["ray_offset_world"])
    below = 2 * np.pi if ds.attrs["bake"]["below_horizon"] == "one" else 0.0
    gaps, errs = [], []
    for v in verts:
        dirs = d_local @ frames[v]  # local (t, b, n) -> world
        o = pos[v] + offset * frames[v, 2]
        hit = rays_hit(o, dirs, pos[faces])
        open_body = 2 * np.pi * (1 - hit[:, is_body].any(axis=1).mean())
        open_all = 2 * np.pi * (1 - hit.any(axis=1).mean())
        baked = ds.visibility[f][v, 0] / Y00 - below
        gaps.append(open_body - open_all)
        errs.append(baked - open_all)
    gaps, errs = np.array(gaps), np.array(errs)
    covered = gaps > 0.5
    assert covered.sum() >= 4, gaps  # the cape covers the back
    assert np.abs(errs).mean() < 0.3, errs  # the bake sees what the rays see (64 rays per vertex: noisy)
    assert np.abs(errs[covered]).mean() < 0.5 * gaps[covered].mean(), (errs, gaps)  # not the body alone


def test_missing_cache_and_no_simulator_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    cape_run: Path) -> None:
    """No MuJoCo: a cloth run without its cache stops with one line naming the missing sequences and the fix;
    a run whose cache is complete still bakes (nothing to simulate)."""
    from prt_torch.bake.runner import run_bake

    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` raises ModuleNotFoundError
    cfg = config_from_dict({**TINY_CAPE, "run_dir": str(tmp_path / "nocache")})
    with pytest.raises(PrtError, match=r"^cloth run 'cape_tiny': the vertex cache .* lacks 3 sequence\(s\) "
                                       r"\(walk\[0:5\], squat\[0:5\], wave\[0:4\]\) and the simulator cannot run "
                                       r"\(mujoco not installed") as e:
        run_bake(cfg, workers=1, progress=False)
    assert "\n" not in str(e.value) and not (tmp_path / "nocache" / "dataset.zarr").exists()
    done = run_bake(config_from_dict({**TINY_CAPE, "run_dir": str(cape_run)}), workers=1, progress=False)
    assert done.frames == 0 and done.skipped == RunDir(cape_run).dataset().n_frames


def test_cape_ships_the_local_network(cape_run: Path) -> None:
    """``train.local.default: mlp``: prt export ships local.onnx + local.npz; the player's visibility (numpy
    offsets in its own frames, then onnxruntime) is the torch model's on the baked frames, split and pipeline play
    the same radiance, and the fused graph mode is a one-line error."""
    from prt_torch.cloth.player import DeformablePlayer
    from prt_torch.local.models import load_local

    code, err = prt("export", str(cape_run))
    assert code == 0, err
    run = RunDir(cape_run)
    meta = run.export_meta()
    assert meta["local"]["kind"] == "mlp" and meta["local"]["parity"]["rel_error"] < 1e-5
    assert run.local_graph_path.is_file() and run.local_data_path.is_file()
    ds = run.dataset()
    held = ds.split("heldout", extra=("positions", "frames"))
    pos = held.extra["positions"]
    model = load_local(run.local_model_path("mlp"))
    split = DeformablePlayer(cape_run, graph="split")
    vis = split.visibility_from_positions(pos)
    np.testing.assert_allclose(vis, model.predict(pos, held.extra["frames"]), atol=2e-4)
    pipe = DeformablePlayer(cape_run, graph="pipeline")
    seq = split.make_sequence(pos, held.pose[:, -split.n_body:] if split.n_body else None)
    a = [r for _, r in split.compute_stream(seq, len(pos))]
    b = [r for _, r in pipe.compute_stream(seq, len(pos))]
    # the same graphs and inputs, but the pipeline's sessions run one intra-op thread each: onnxruntime may split
    # its GEMMs otherwise; a radiance value is a float32 chain of <= 512 roundings (the local network's widths,
    # C^2 and k C of the shading) of terms bounded by 4 max|radiance|
    ra, rb = np.concatenate(a), np.concatenate(b)
    np.testing.assert_allclose(rb, ra, rtol=0, atol=two_path_atol(512, 4 * np.abs(ra).max()))
    with pytest.raises(PrtError, match="ships a local visibility model") as e:
        DeformablePlayer(cape_run, graph="fused")
    assert "\n" not in str(e.value)


def test_cape_local_bench_and_torch_free_player(cape_run: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """`prt bench play` on a run shipping a local network: the per-cluster rows and the local rows side by side,
    each ratio the quotient of the medians it names; `prt play --sequence` of it never imports torch."""
    from prt_torch.cli import main

    if not RunDir(cape_run).local_graph_path.is_file():
        assert prt("export", str(cape_run))[0] == 0
    capsys.readouterr()
    assert main(["bench", "play", str(cape_run), "--frames", "5", "--repeats", "1", "--warmup", "1", "--precisions",
                 "fp32", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ms, r = out["steps_ms"], out["ratios"]
    assert out["local"] == "mlp" and {"local_offsets", "local_visibility", "frame_split_local",
                                      "stream_pipeline_local"} <= set(ms)
    assert r["sequence playback: local pipeline / per-cluster pipeline"] == pytest.approx(
        ms["stream_pipeline_local"] / ms["stream_pipeline"])
    assert out["fps_pipeline_local"] == pytest.approx(1e3 / ms["stream_pipeline_local"])
    from tests.torchfree import run_cli_without_torch

    name = RunDir(cape_run).dataset().splits["heldout"][0]
    run_cli_without_torch(["play", str(cape_run), "--sequence", name, "--max-frames", "2", "--out",
                           str(tmp_path / "cape.mp4")])  # pipelined, the local network
    assert (tmp_path / "cape.mp4").stat().st_size > 0
