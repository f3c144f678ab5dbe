"""``prt compare``'s floor with peak lights (issue 27): ``ground.with_peaks`` (``truth+peaks_exact``, ``shexp+peaks_
<kind>``) and every floor row's ``vs_reference`` figures against the Monte-Carlo floor
(:func:`prt_torch.compare.reference.reference_radiance` on the floor vertices, traced against the floor and the posed
character, the sun a disk of the peak's radius).

Independent references: the Monte-Carlo floor (Embree rays, the analytic Lambert BRDF, the light at full resolution,
no SH); the irradiance of an unshadowed floor vertex by quadrature of the sky's radiance function plus ``E cos``.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest_plugins = ["tests.fixtures_peaks"]

#: the keys of every floor row (the SHEXP floor's figures) and of every ``vs_reference``
FIGURES = {"psnr_image", "radiance_rel_rmse", "psnr_vertex"}


@pytest.fixture(scope="module")
def ground_result(peak_run: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    from prt_torch.compare.ground import compare_scene
    from prt_torch.compare.reference import compare_lights
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.rundir import RunDir
    from prt_torch.scene.config import scene_from_dict
    from prt_torch.scoring.rpos import player_brdfs

    dst = tmp_path_factory.mktemp("ground_peaks") / "run"
    shutil.copytree(peak_run, dst)
    run = RunDir(dst)
    if not (run.shexp_path.is_file() and run.blockers_path.is_file()):
        from prt_torch.shexp.graph import ship_shexp

        ship_shexp(run, run.character(), int(run.export_meta()["sh_order"]), 24)
    ctx = load_compare_run(dst)
    fs = heldout_frames(ctx, 2)
    lights = compare_lights("sky", None, ctx.order, "auto")
    rpos, _ = player_brdfs(ctx.order, ctx.run, ctx.character)
    cat = {b: r for b, r in rpos.items() if b in ("lambert", "phong")}
    scene = scene_from_dict({"ground": {"resolution": 16}, "characters": [{}]})
    res = compare_scene(ctx, fs, lights.lighting, cat, scene=scene, image_frames=2, lights=lights,
                        reference_frames=1, reference_rays=256)
    return res, dst


def test_floor_rows_and_schema(ground_result) -> None:
    from prt_torch.compare.ground import scene_markdown

    res, run = ground_result
    g = res["ground"]
    assert FIGURES | {"vis_rel_err"} <= set(g) and set(g["vs_reference"]) == FIGURES
    rows = g["with_peaks"]
    assert list(rows) == ["truth+peaks_exact", "shexp+peaks_exact", "shexp+peaks_spheres", "shexp+peaks_learned"]
    for r in rows.values():
        assert FIGURES | {"vis_rel_err", "peak_vis_rel_err", "ms_per_frame", "fps"} <= set(r)
        assert set(r["vs_reference"]) == FIGURES
    assert rows["truth+peaks_exact"]["radiance_rel_rmse"] == 0 and rows["shexp+peaks_exact"]["peak_vis_rel_err"] == 0
    ref = g["reference"]
    assert ref["frames"] == 1 and ref["rays_per_estimate"] >= 1024 and "disk" in ref["lighting"]
    assert (Path(run) / "compare" / "ground.png").is_file()
    md = "\n".join(scene_markdown(res))
    assert "ground (shexp+peaks_learned)" in md and "Monte-Carlo reference" in md


def test_floor_with_peaks_matches_the_reference(ground_result) -> None:
    """The ceiling (Embree SH residual + Embree peaks) is the reference up to its noise and the residual's SH;
    the whole light on the SH path (no peaks) is far from it (the sun smeared by order-3 SH and the window); the
    sphere peak kinds lie in between, much closer to the ceiling."""
    g = ground_result[0]["ground"]
    rows = g["with_peaks"]
    noise = g["reference"]["noise"]["radiance_rel_rmse"]
    ceiling = rows["truth+peaks_exact"]["vs_reference"]["radiance_rel_rmse"]
    plain = g["vs_reference"]["radiance_rel_rmse"]
    assert noise < 0.01 and ceiling < 0.03 and plain > 3 * ceiling
    for n in ("shexp+peaks_exact", "shexp+peaks_spheres", "shexp+peaks_learned"):
        assert rows[n]["vs_reference"]["radiance_rel_rmse"] < 0.5 * plain
        assert rows[n]["vs_reference"]["psnr_image"] > g["vs_reference"]["psnr_image"]


def test_reference_floor_irradiance_by_quadrature(peak_run: Path) -> None:
    """The floor's Monte-Carlo reference at vertices nothing shadows is the sky's irradiance by quadrature of its
    radiance function plus the sun's ``E cos``, times albedo / pi."""
    from prt_torch.compare.ground import GroundReference
    from prt_torch.compare.reference import compare_lights, sky_radiance
    from prt_torch.scene.ground import make_ground
    from prt_torch.sh.quadrature import hemisphere_directions

    lights = compare_lights("sky", None, 3, "auto")
    g = make_ground((0.0, 0.0), 4.0, 0.0, 4, (0.5, 0.6, 0.7))
    far = [(np.array([[50.0, 50.0, 1.0], [50.1, 50.0, 1.0], [50.0, 50.1, 1.0]], np.float32), np.array([[0, 1, 2]]))]
    ref = GroundReference(lights.reference, 1, 2048, 1e-4, [[(g.vertices, g.faces), *far]])
    ea, eb = ref.estimates(g, 0, np.array([0.0, -5.0, 3.0]), g.albedo)
    w = hemisphere_directions(200_000, seed=3)
    pk = lights.peaks[0]
    irr = (sky_radiance()(w) * w[:, 2:3]).mean(0) * 2 * math.pi + pk.power * pk.direction[2]
    np.testing.assert_allclose(0.5 * (ea + eb), np.broadcast_to(irr * g.albedo / math.pi, ea.shape), rtol=0.01)


def test_floor_receives_learned_capsules(peak_run: Path, tmp_path: Path) -> None:
    """The default learned blockers are capsules (``train.peaks.blockers``): compare's floor casts them (the cone
    kernel with their segments, the scene player's rule) and is closer to the Monte-Carlo floor than the whole light on
    SH. The run's learned blockers are replaced by the character's rest capsules (what the capsule fit starts from),
    recorded in ``model.json`` as ``prt train`` records them."""
    import json

    from prt_torch.blockers.capsules import CapsuleSet, fit_capsules, load_blocker_set
    from prt_torch.compare.ground import compare_scene
    from prt_torch.compare.reference import compare_lights
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.rundir import RunDir, file_sha256
    from prt_torch.scene.config import scene_from_dict
    from prt_torch.scoring.rpos import player_brdfs

    dst = tmp_path / "run"
    shutil.copytree(peak_run, dst)
    run = RunDir(dst)
    fit_capsules(run.character()).save(run.peak_blockers_path)
    meta = json.loads(run.model_json.read_text())
    meta["files"][run.peak_blockers_path.name] = file_sha256(run.peak_blockers_path)
    run.model_json.write_text(json.dumps(meta))
    assert isinstance(load_blocker_set(run.peak_blockers_path), CapsuleSet)
    ctx = load_compare_run(dst)
    fs = heldout_frames(ctx, 2)
    lights = compare_lights("sky", None, ctx.order, "auto")
    rpos, _ = player_brdfs(ctx.order, ctx.run, ctx.character)
    scene = scene_from_dict({"ground": {"resolution": 16}, "characters": [{}]})
    res = compare_scene(ctx, fs, lights.lighting, {"lambert": rpos["lambert"]}, scene=scene, image_frames=1,
                        lights=lights, reference_frames=1, reference_rays=256)
    g = res["ground"]
    learned = g["with_peaks"]["shexp+peaks_learned"]["vs_reference"]
    assert learned["radiance_rel_rmse"] < 0.5 * g["vs_reference"]["radiance_rel_rmse"]
