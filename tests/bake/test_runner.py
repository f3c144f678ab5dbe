"""The bake job end to end: determinism across backends, resume after SIGKILL, store checks, ground truth."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr

from prt_torch.bake.directions import hemisphere_set, vertex_angles
from prt_torch.bake.runner import bake, run_bake
from prt_torch.bake.store import open_dataset
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from tests.raycast import rays_hit
from tests.tolerance import assert_bitwise

RESULT_ARRAYS = ("positions", "normals", "frames", "visibility", "done", "pose", "clip_id", "frame_index", "cluster",
                 "cluster_axis", "cluster_bone", "faces")


def tiny_config(run_dir: Path, **bake: object) -> dict:
    """~550 vertices, 64 rays, 25 frames (14 random + squat at 3 fps held out), 4 frames per task."""
    return {
        "name": "tiny",
        "run_dir": str(run_dir),
        "character": {"source": "builtin", "density": 0.05, "fps": 3.0, "random_poses": 14,
                      "heldout_clips": ["squat"], "seed": 1},
        "bake": {"order": 3, "n_rays": 64, "frames_per_task": 4, "seed": 7, "below_horizon": "zero", **bake},
    }


def read_all(path: Path) -> dict[str, np.ndarray]:
    g = zarr.open_group(str(path), mode="r")
    return {name: np.asarray(g[name][:]) for name in RESULT_ARRAYS if name in g}


def assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert_bitwise(a[k], b[k], err_msg=k, why='the bake is bit-exact whatever runs its blocks')


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    """An uninterrupted in-process bake of the tiny config."""
    run_dir = tmp_path_factory.mktemp("ref")
    path = bake(config_from_dict(tiny_config(run_dir)), workers=1, progress=False)
    return path, read_all(path)


def test_dataset_layout_and_basic_properties(reference: tuple[Path, dict[str, np.ndarray]]) -> None:
    path, arrays = reference
    ds = open_dataset(path)
    F, V = ds.n_frames, ds.n_vertices
    assert ds.complete and ds.clip_names == ["random", "squat"]
    assert ds.splits == {"train": ["random"], "heldout": ["squat"]}
    assert ds.train_mask.sum() == 14 and ds.heldout_mask.sum() == F - 14
    assert arrays["visibility"].shape == (F, V, 9) and arrays["visibility"].dtype == np.float32
    assert arrays["frames"].shape == (F, V, 3, 3)
    assert ds.array("visibility").chunks == (4, V, 9)  # chunks align with tasks
    # DC term lies between 0 (fully occluded) and the open hemisphere's 2 pi y00
    dc = arrays["visibility"][..., 0]
    assert dc.min() >= 0 and dc.max() <= 2 * math.pi / math.sqrt(4 * math.pi) + 1e-5
    np.testing.assert_allclose(arrays["frames"][..., 2, :], arrays["normals"], atol=1e-6)
    ch = ds.character()
    assert ch.content_hash() == ds.character_hash
    pos, _ = ch.skin_mesh(ch.pose("squat", fps=3.0))
    np.testing.assert_allclose(arrays["positions"][ds.heldout_mask], pos, atol=1e-5)
    for key in ("character_hash", "sh_order", "n_rays", "conventions", "versions", "config"):
        assert key in ds.attrs


def moller_trumbore_any(origin: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Brute force: does each ray ``origin + s dirs[r]`` (s > 0) hit any triangle ``tri (T, 3, 3)``? -> (R,) bool."""
    return rays_hit(origin, dirs, tri, t_min=0.0).any(axis=1)


def test_visibility_matches_independent_ray_casting(reference: tuple[Path, dict[str, np.ndarray]]) -> None:
    """Recompute a few vertices with a brute-force numpy ray tracer (not Embree) and direct SH quadrature."""
    path, arrays = reference
    ds = open_dataset(path)
    f = 17
    V = ds.n_vertices
    tri = arrays["positions"][f].astype(np.float64)[ds.faces]
    rng = np.random.default_rng(0)
    verts = rng.choice(V, 12, replace=False)
    R, order = 64, 3
    d = hemisphere_set(R)
    phi = vertex_angles(V, seed=7)
    offset = ds.attrs["bake"]["ray_offset_world"]
    worst = 0.0
    for v in verts:
        F = arrays["frames"][f, v].astype(np.float64)
        c, s = math.cos(phi[v]), math.sin(phi[v])
        local = d @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])  # Rz(phi) d (rows)
        world = local @ F  # F^T (Rz d)
        origin = arrays["positions"][f, v] + offset * F[2]
        hit = moller_trumbore_any(origin.astype(np.float64), world, tri)
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        ref = (2 * math.pi / R) * ((~hit).astype(np.float64) @ sh_basis(local, order))
        worst = max(worst, float(np.abs(ref - arrays["visibility"][f, v]).max()))
    # one grazing ray decided differently by the two tracers moves a coefficient by <= 2 pi / R * max|y|
    assert worst <= 2 * (2 * math.pi / R) * 0.8


def test_pool_and_dask_bakes_equal_in_process_bake(tmp_path: Path, reference: tuple[Path, dict]) -> None:
    pool = bake(config_from_dict(tiny_config(tmp_path / "pool")), workers=2, progress=False)
    assert_same(read_all(pool), reference[1])

    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1",
                      dashboard_address=None, protocol="tcp://") as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1")
        res = run_bake(config_from_dict(tiny_config(tmp_path / "dask")), scheduler=cluster.scheduler_address,
                       progress=False)
    assert res.frames == len(reference[1]["done"])
    assert_same(read_all(res.path), reference[1])


def test_rerun_skips_completed_frames(tmp_path: Path, reference: tuple[Path, dict]) -> None:
    cfg = config_from_dict(tiny_config(tmp_path))
    first = run_bake(cfg, workers=1, progress=False)
    chunk = first.path / "visibility" / "c" / "0" / "0" / "0"
    mtime = chunk.stat().st_mtime_ns
    again = run_bake(cfg, workers=1, progress=False)
    n = len(reference[1]["done"])
    assert again.frames == 0 and again.skipped == n
    assert chunk.stat().st_mtime_ns == mtime
    # lose one block: only that block is baked again, and the result is unchanged
    g = zarr.open_group(str(first.path), mode="r+")
    g["done"][8:12] = np.zeros(4, dtype=bool)
    g["visibility"][8:12] = np.zeros_like(g["visibility"][8:12])
    third = run_bake(cfg, workers=1, progress=False)
    assert third.frames == 4 and third.skipped == n - 4
    assert_same(read_all(first.path), reference[1])


@pytest.mark.parametrize("when", ["early", "midway"])
def test_sigkill_then_resume_equals_uninterrupted(tmp_path: Path, reference: tuple[Path, dict], when: str) -> None:
    """SIGKILL a real bake subprocess (early: as soon as its run directory appears, i.e. while the
    character/store are being written; midway: after >= 1 block is done), resume, compare bitwise."""
    cfg_path = tmp_path / "tiny.json"
    cfg_path.write_text(json.dumps(tiny_config(tmp_path / "run")))
    code = ("import json, sys; from prt_torch.config import config_from_dict; from prt_torch.bake.runner import bake; "
            "bake(config_from_dict(json.load(open(sys.argv[1]))), workers=1, progress=False)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(cfg_path)])
    run_dir = tmp_path / "run"
    done_path = run_dir / "dataset.zarr"
    killed_at = None
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if when == "early" and run_dir.exists():
                os.kill(proc.pid, signal.SIGKILL)
                killed_at = 0
                break
            if when == "midway" and (done_path / "zarr.json").exists():
                done = np.asarray(zarr.open_group(str(done_path), mode="r")["done"][:])
                if 4 <= done.sum() < len(done):  # at least one block in, some still to go
                    os.kill(proc.pid, signal.SIGKILL)
                    killed_at = int(done.sum())
                    break
            time.sleep(0.005)
    finally:
        if proc.poll() is None and killed_at is None:
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    if killed_at is None:
        pytest.fail(f"the bake finished before it could be killed ({when})")
    assert proc.returncode == -signal.SIGKILL
    res = run_bake(config_from_dict(tiny_config(run_dir)), workers=1, progress=False)
    assert res.skipped >= killed_at and res.frames + res.skipped == len(reference[1]["done"])
    assert_same(read_all(res.path), reference[1])
    assert not list(res.path.rglob("*.partial")) and not list(run_dir.glob(".dataset.zarr.tmp-*"))


def _snapshot(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


def test_mismatched_dataset_is_refused_and_untouched(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = tiny_config(tmp_path)
    cfg["character"]["random_poses"] = 4
    cfg["character"]["heldout_clips"] = []
    bake(config_from_dict(cfg), workers=1, progress=False)
    before = _snapshot(tmp_path)
    from prt_torch.bake import plan as plan_mod

    real_load = plan_mod.load_character

    def other_character(c: object) -> object:  # the same rig with the rest mesh scaled by 1%
        ch = real_load(c)
        ch.rest_vertices = ch.rest_vertices * np.float32(1.01)
        return ch

    with monkeypatch.context() as m:
        m.setattr(plan_mod, "load_character", other_character)
        with pytest.raises(PrtError, match="another character"):
            bake(config_from_dict(cfg), workers=1, progress=False)
    other_rays = {**cfg, "bake": {**cfg["bake"], "n_rays": 128}}
    with pytest.raises(PrtError, match="n_rays"):
        bake(config_from_dict(other_rays), workers=1, progress=False)
    other_frames = {**cfg, "character": {**cfg["character"], "seed": 2}}
    with pytest.raises(PrtError, match="frame list"):
        bake(config_from_dict(other_frames), workers=1, progress=False)
    assert _snapshot(tmp_path) == before


def test_bad_config_and_inputs_write_nothing(tmp_path: Path) -> None:
    bad = tiny_config(tmp_path / "a")
    bad["bake"]["n_raysss"] = 3
    with pytest.raises(PrtError, match="unknown config key 'bake.n_raysss'"):
        config_from_dict(bad)
    unknown_clip = tiny_config(tmp_path / "b")
    unknown_clip["character"]["heldout_clips"] = ["moonwalk"]
    with pytest.raises(PrtError, match="unknown clip 'moonwalk'"):
        bake(config_from_dict(unknown_clip), workers=1, progress=False)
    assert not (tmp_path / "b").exists()
    # CLI: one-line error, exit status 2
    cfg_file = tmp_path / "bad.yaml"
    cfg_file.write_text("name: x\ncharacter: {source: builtin}\nbake: {colour: red}\n")
    out = subprocess.run([sys.executable, "-m", "prt_torch.cli", "bake", str(cfg_file)], capture_output=True,
                         text=True)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "unknown config key 'bake.colour'" in out.stderr


def test_nan_pose_is_refused_before_writing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from prt_torch.rig.builtin import make_character

    ch = make_character(0.05, fps=3.0)
    clip = ch.clips["squat"]
    clip.local[2, 3, 0, 3] = np.nan  # a NaN joint translation -> NaN posed positions
    cfg = config_from_dict(tiny_config(tmp_path / "nan"))
    monkeypatch.setattr("prt_torch.bake.plan.load_character", lambda _cfg: ch)
    with pytest.raises(PrtError, match="NaN"):
        bake(cfg, workers=1, progress=False)
    assert not (tmp_path / "nan").exists()


def test_transfer_is_stored_and_consistent_with_visibility(tmp_path: Path) -> None:
    """Same rays: the direct transfer's DC equals y00/pi * v_10 / sqrt(3/4pi) (the cosine is the local z)."""
    cfg = tiny_config(tmp_path / "direct", transfer=True, transfer_order=4)
    cfg["character"].update(random_poses=4, heldout_clips=[])
    ds = open_dataset(bake(config_from_dict(cfg), workers=1, progress=False))
    t = ds.transfer
    assert t is not None and t.shape == (4, ds.n_vertices, 16)
    y00, y10 = 1 / math.sqrt(4 * math.pi), math.sqrt(3 / (4 * math.pi))
    np.testing.assert_allclose(t[..., 0], y00 / math.pi * ds.visibility[..., 2] / y10, atol=1e-5)
    cfg_b = tiny_config(tmp_path / "bounce", transfer=True, transfer_order=4, bounces=1)
    cfg_b["character"].update(random_poses=4, heldout_clips=[])
    tb = open_dataset(bake(config_from_dict(cfg_b), workers=1, progress=False)).transfer
    assert tb is not None and np.all(tb[..., 0] >= t[..., 0] - 1e-6) and (tb[..., 0] - t[..., 0]).max() > 1e-3


def test_gltf_fox_bakes(tmp_path: Path, shared_data: Path) -> None:
    """The glTF path of configs/fox.yaml (Survey + Walk train, Run held out), few rays and frames."""
    cfg = {"name": "fox", "run_dir": str(tmp_path),
           "character": {"source": str(shared_data / "characters" / "Fox.glb"), "height": 1.8, "fps": 5.0,
                         "train_clips": ["Walk"], "heldout_clips": ["Run"]},
           "bake": {"order": 3, "n_rays": 32, "frames_per_task": 4, "below_horizon": "zero"}}
    ds = open_dataset(bake(config_from_dict(cfg), workers=1, progress=False))
    assert ds.complete and ds.clip_names == ["Walk", "Run"] and ds.heldout_mask.sum() > 0
    dc = ds.visibility[..., 0]
    assert 0 <= dc.min() and dc.max() <= 2 * math.pi / math.sqrt(4 * math.pi) + 1e-5
    assert ds.character().content_hash() == ds.character_hash
