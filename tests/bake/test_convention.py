"""The visibility convention below the horizon (``bake.below_horizon``): "zero" (docs/DESIGN.md) or "one"
(seed 003 eq. 1), in the bake, the store, and every reader of the unshadowed visibility."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from prt_torch.bake.embree import RayScene
from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.errors import PrtError
from tests.bake.test_visibility import ORDER, cap_sh, frame_about_z, mc_sigma

SQRT_4PI = math.sqrt(4 * math.pi)


def constant_one(order: int) -> np.ndarray:
    """SH of the constant 1: ``sqrt(4 pi) e_0``."""
    out = np.zeros(order * order)
    out[0] = SQRT_4PI
    return out


@pytest.fixture(scope="module")
def plane_mesh() -> trimesh.Trimesh:
    plane = trimesh.creation.box(extents=(200.0, 200.0, 1.0))
    plane.apply_translation((0.0, 0.0, -0.5))
    return plane


def test_one_unoccluded_vertex_is_the_constant(plane_mesh: trimesh.Trimesh) -> None:
    """"one": every upper ray escapes, so v is the constant 1 exactly (no quadrature error, DC only)."""
    scene = RayScene(plane_mesh.vertices, plane_mesh.faces)
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-5, 5, (6, 2)), np.zeros(6)]
    frames = np.stack([frame_about_z(a) for a in rng.uniform(0, 2 * math.pi, 6)])
    for n_rays in (64, 512):
        rays = RaySet.make(n_rays, ORDER, 6, seed=0, below_horizon="one")
        vis = trace_frame(pts, frames, None, rays, offset=1e-4, scene=scene).visibility
        np.testing.assert_allclose(vis, np.broadcast_to(constant_one(ORDER), vis.shape), rtol=0, atol=1e-6)


@pytest.mark.parametrize("below", ["zero", "one"])
@pytest.mark.parametrize("tilt", [0.0, 0.5])
def test_plane_under_sphere_matches_closed_form(plane_mesh: trimesh.Trimesh, tilt: float, below: str) -> None:
    """Plane under a sphere: "zero" = hemisphere minus the cap, "one" = the constant 1 minus the cap."""
    h, rho = 2.0, 1.0
    axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=rho)
    sphere.apply_translation(h * axis)
    mesh = trimesh.util.concatenate([plane_mesh, sphere])
    scene = RayScene(mesh.vertices, mesh.faces)
    c0 = math.sqrt(1 - (rho / h) ** 2)
    frame = frame_about_z(1.1)
    n_rays = 2048
    rays = RaySet.make(n_rays, ORDER, 1, seed=5, below_horizon=below)
    vis = trace_frame(np.zeros((1, 3)), frame[None], None, rays, offset=1e-5, scene=scene).visibility[0]
    axis_local = frame @ axis
    free = cap_sh(np.array([0.0, 0.0, 1.0]), 0.0, ORDER) if below == "zero" else constant_one(ORDER)
    ref = free - cap_sh(axis_local, c0, ORDER)
    cap_solid_angle = 2 * math.pi * (1 - c0)
    total = 2 * math.pi if below == "zero" else 4 * math.pi
    assert vis[0] == pytest.approx((total - cap_solid_angle) / SQRT_4PI, abs=0.01)
    # the traced part: the visible rays ("zero") or the occluded ones ("one")
    sigma = mc_sigma(lambda d: ((d @ axis_local) < c0) == (below == "zero"), ORDER, n_rays)
    assert np.all(np.abs(vis - ref) <= 3 * sigma + 2e-3), (vis - ref, sigma)
    # the two conventions differ by exactly the lower-hemisphere indicator taken with the same rays
    other = RaySet.make(n_rays, ORDER, 1, seed=5, below_horizon="one" if below == "zero" else "zero")
    vis2 = trace_frame(np.zeros((1, 3)), frame[None], None, other, offset=1e-5, scene=scene).visibility[0]
    one, zero = (vis, vis2) if below == "one" else (vis2, vis)
    free_rays = trace_frame(np.zeros((1, 3)), frame[None], None,
                            RaySet.make(n_rays, ORDER, 1, seed=5), offset=1e-5,
                            scene=RayScene(np.asarray(plane_mesh.vertices), np.asarray(plane_mesh.faces))).visibility[0]
    np.testing.assert_allclose(one - zero, constant_one(ORDER) - free_rays, atol=2e-5)


def test_bad_convention_is_one_line() -> None:
    with pytest.raises(PrtError, match="below_horizon") as e:
        RaySet.make(64, ORDER, 2, seed=0, below_horizon="half")
    assert "\n" not in str(e.value)


def test_unshadowed_follows_the_convention() -> None:
    """The player's and eval's unshadowed visibility: hemisphere for "zero" (and old data), constant for "one"."""
    from prt_torch.bake.store import below_horizon_of
    from prt_torch.compare.methods.unshadowed import Unshadowed
    from prt_torch.player.lighting import hemisphere_visibility
    from prt_torch.scoring.lighting import unshadowed_visibility

    hemi = cap_sh(np.array([0.0, 0.0, 1.0]), 0.0, ORDER)
    np.testing.assert_allclose(hemisphere_visibility(ORDER), hemi, atol=1e-6)
    np.testing.assert_allclose(hemisphere_visibility(ORDER, "one"), constant_one(ORDER), atol=1e-6)
    for attrs, want in (({}, hemi), ({"bake": {"order": 4}}, hemi), ({"bake": {"below_horizon": "zero"}}, hemi),
                        ({"bake": {"below_horizon": "one"}}, constant_one(ORDER)),
                        ({"below_horizon": "one"}, constant_one(ORDER)), ("one", constant_one(ORDER))):
        np.testing.assert_allclose(unshadowed_visibility(ORDER, attrs), want, atol=1e-6, err_msg=str(attrs))
    assert below_horizon_of({"bake": {}}) == "zero"
    with pytest.raises(PrtError, match="below_horizon"):
        unshadowed_visibility(ORDER, {"bake": {"below_horizon": "two"}})
    with pytest.raises(PrtError, match="below_horizon"):
        hemisphere_visibility(ORDER, "two")
    for bake, want in (({"order": ORDER}, hemi), ({"order": ORDER, "below_horizon": "one"}, constant_one(ORDER))):
        m = Unshadowed()
        m.prepare(SimpleNamespace(order=ORDER, bake=bake, n_vertices=3), None)  # type: ignore[arg-type]
        got = m.visibility(SimpleNamespace(index=np.arange(2)))  # type: ignore[arg-type]
        assert got.shape == (2, 3, ORDER * ORDER)
        np.testing.assert_allclose(got[1, 2], want, atol=1e-6)


def tiny_config(run_dir: Path, **bake: object) -> dict:
    """~550 vertices, 32 rays, 7 frames (3 random + squat at 1 fps held out)."""
    return {
        "name": "tiny",
        "run_dir": str(run_dir),
        "character": {"source": "builtin", "density": 0.05, "fps": 1.0, "random_poses": 3,
                      "train_clips": ["stretch"], "heldout_clips": ["squat"], "seed": 1},
        "bake": {"order": 3, "n_rays": 32, "frames_per_task": 4, "seed": 7, **bake},
        "train": {"kinds": ["linear"], "default_kind": "linear", "alphas": [1.0], "folds": 2, "seed": 0},
    }


@pytest.fixture(scope="module")
def one_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny run baked with below_horizon "one" (run directory)."""
    from prt_torch.bake.runner import bake
    from prt_torch.config import config_from_dict

    run_dir = tmp_path_factory.mktemp("one")
    bake(config_from_dict(tiny_config(run_dir, below_horizon="one")), workers=1, progress=False)
    return run_dir


def test_store_records_the_convention_and_refuses_the_other(one_run: Path) -> None:
    from prt_torch.bake.runner import bake
    from prt_torch.bake.store import below_horizon_of, open_dataset
    from prt_torch.config import config_from_dict

    ds = open_dataset(one_run)
    assert ds.attrs["bake"]["below_horizon"] == "one"
    assert ds.attrs["conventions"]["below_horizon"] == "one"
    assert "1 below the horizon" in ds.attrs["conventions"]["visibility"]
    assert below_horizon_of(ds.attrs) == "one"
    with pytest.raises(PrtError, match=r"bake\.below_horizon='one', the config has 'zero'") as e:
        bake(config_from_dict(tiny_config(one_run, below_horizon="zero")), workers=1, progress=False)
    assert "\n" not in str(e.value)
    # the same convention resumes (nothing left to do)
    bake(config_from_dict(tiny_config(one_run, below_horizon="one")), workers=1, progress=False)


def test_store_without_the_key_is_zero(tmp_path: Path) -> None:
    """Stores baked before the setting existed are "zero": they resume with a config that pins "zero" and
    refuse "one" (the default since issue 9) with one line."""
    import zarr

    from prt_torch.bake.runner import bake
    from prt_torch.bake.store import below_horizon_of, open_dataset
    from prt_torch.config import config_from_dict

    cfg = tiny_config(tmp_path, below_horizon="zero")
    cfg["character"]["random_poses"] = 1
    cfg["character"]["train_clips"] = []
    path = bake(config_from_dict(cfg), workers=1, progress=False)
    g = zarr.open_group(str(path), mode="r+")
    b = dict(g.attrs["bake"])
    del b["below_horizon"]
    g.attrs["bake"] = b
    assert below_horizon_of(open_dataset(path).attrs) == "zero"
    bake(config_from_dict(cfg), workers=1, progress=False)
    with pytest.raises(PrtError, match=r"bake\.below_horizon='zero', the config has 'one'"):
        bake(config_from_dict({**cfg, "bake": {**cfg["bake"], "below_horizon": "one"}}), workers=1, progress=False)


def test_one_dataset_readers_follow(one_run: Path) -> None:
    """sh_truth re-traces the stored "one" visibility; the export records "one" and the player follows it;
    an export without the key (older) is "zero"."""
    from prt_torch.bake.store import open_dataset
    from prt_torch.compare.methods.sh_truth import ShTruth
    from prt_torch.config import config_from_dict
    from prt_torch.export.run import export_run
    from prt_torch.fit.train import train
    from prt_torch.player.bundle import RunBundle
    from prt_torch.player.lighting import hemisphere_visibility
    from prt_torch.player.player import Player

    ds = open_dataset(one_run)
    ch = ds.character()
    rows = ds.split_rows("heldout")[:2]
    data = ds.rows(rows, ("visibility", "positions", "frames"))
    m = ShTruth()
    m.prepare(SimpleNamespace(bake=ds.attrs["bake"], n_vertices=ch.num_vertices, character=ch), None)  # type: ignore[arg-type]
    got = m.visibility(SimpleNamespace(positions=data["positions"], frames=data["frames"]))  # type: ignore[arg-type]
    np.testing.assert_allclose(got, data["visibility"], atol=1e-5)

    train(config_from_dict(tiny_config(one_run, below_horizon="one")))
    meta = export_run(one_run, brdfs=("lambert",))
    assert meta["below_horizon"] == "one"
    assert "one below the horizon" in meta["conventions"]
    bundle = RunBundle(one_run, graphs=("visibility",))
    assert bundle.below_horizon == "one"
    assert bundle.graphs["visibility"].metadata["prt.below_horizon"] == "one"
    p = Player(one_run, brdf="lambert", window_size=(64, 48))
    try:
        np.testing.assert_allclose(p.unshadowed, constant_one(3), atol=1e-6)
    finally:
        close = getattr(p, "close", None)
        if close is not None:
            close()
    export_json = Path(one_run) / "export.json"
    old = json.loads(export_json.read_text())
    old.pop("below_horizon")
    export_json.write_text(json.dumps(old))
    bundle = RunBundle(one_run, graphs=("visibility",))
    assert bundle.below_horizon == "zero"
    np.testing.assert_allclose(hemisphere_visibility(3, bundle.below_horizon), hemisphere_visibility(3), atol=0)
    old["below_horizon"] = "half"
    export_json.write_text(json.dumps(old))
    with pytest.raises(PrtError, match="below_horizon") as e:
        RunBundle(one_run, graphs=("visibility",))
    assert "\n" not in str(e.value)
