"""``prt compare`` on ``small_run``: schema, truth = bake, registry, files, CLI errors; the MC reference."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.cli import main
from prt_torch.rundir import RunDir

LEARNED = ("learned_linear", "learned_quadratic", "learned_mlp")
KEYS = {"vis_rel_err", "radiance_rel_rmse", "psnr_image_diffuse", "psnr_image_glossy", "bytes", "ms_per_frame", "fps"}


#: the compare directory as ``compared`` wrote it (other tests compare the same run again, in any order)
SNAPSHOT: dict[str, Path] = {}


@pytest.fixture(scope="module")
def compared(small_run: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    import shutil

    from prt_torch.compare import run_compare

    r = run_compare(small_run, max_frames=5, image_frames=2, reference_frames=1, reference_rays=64)
    snap = tmp_path_factory.mktemp("compare_snapshot") / "compare"
    shutil.copytree(RunDir(small_run).compare_dir, snap)
    SNAPSHOT["dir"] = snap
    return r


def test_schema_and_files(small_run: Path, compared: dict[str, Any]) -> None:
    r = compared
    assert r["frames"] == 5 and r["clips"] == ["wave"] and r["brdfs"] == ["lambert", "phong"]
    assert isinstance(r["lighting"], str) and r["lighting_path"] == "lobes"
    # the default methods; shexp is one only for runs exported with a sphere set (small_run is not exported;
    # tests/compare/test_shexp_method.py checks that side)
    assert [n for n in r["methods"] if "+peaks_" not in n] == ["sh_truth", "unshadowed", *LEARNED]  # + peak rows
    for name, m in r["methods"].items():
        assert KEYS <= set(m), name
        assert KEYS <= set(m["vs_reference"]), name
        assert m["ms_per_frame"] > 0 and m["fps"] == pytest.approx(1e3 / m["ms_per_frame"])
        assert m["bytes"] >= 0 and m["runtime"]
        assert m["vs_reference"]["vis_rel_err"] is None
        assert np.isfinite(m["vs_reference"]["psnr_image_diffuse"])
    # sh_truth against itself: no error at all
    t = r["methods"]["sh_truth"]
    assert t["vis_rel_err"] == 0.0 and t["radiance_rel_rmse"] == 0.0
    assert t["psnr_image_diffuse"] == float("inf") and t["psnr_image_glossy"] == float("inf")
    # learned models beat no shadowing, and run on onnxruntime
    u = r["methods"]["unshadowed"]
    for name in LEARNED:
        m = r["methods"][name]
        assert m["vis_rel_err"] < u["vis_rel_err"] and m["radiance_rel_rmse"] < u["radiance_rel_rmse"]
        assert m["psnr_image_diffuse"] > u["psnr_image_diffuse"]
        assert "onnxruntime" in m["runtime"] and m["bytes"] > 1000
    assert r["reference"]["frames"] == 1 and r["reference"]["noise"]["psnr_image_diffuse"] > 25
    run = RunDir(small_run)
    json_p, table_p, html_p, strip_p, scatter_p = (SNAPSHOT["dir"] / p.relative_to(run.compare_dir) for p in (
        run.compare_json, run.compare_table, run.compare_html, run.compare_strip, run.compare_scatter))
    for p in (json_p, table_p, html_p, strip_p, scatter_p):
        assert p.is_file() and p.stat().st_size > 100, p
    assert json.loads(json_p.read_text())["frames"] == 5
    assert "learned_mlp" in table_p.read_text()
    assert strip_p.name in html_p.read_text()
    import imageio.v2 as iio

    strip = iio.imread(strip_p)
    # truth, 4 methods, sh_truth+peaks_exact (the sky's sun: tests/compare/test_compare_peaks.py), reference; 2 rows
    assert strip.shape[1] == 7 * 640 and strip.shape[0] == 2 * 480


def test_scored_frames_and_figures_do_not_depend_on_the_method_list(small_run: Path,
                                                                    compared: dict[str, Any]) -> None:
    """The strip, image and reference frames come from sh_truth vs the unshadowed visibility whatever the methods
    compared: learned_mlp compared alone scores the frames (and so the figures) it scores among all the methods."""
    from prt_torch.compare import run_compare

    alone = run_compare(small_run, methods=["learned_mlp"], max_frames=5, image_frames=2, reference_frames=1,
                        reference_rays=64, peaks=0)
    full = compared
    assert alone["reference"]["frame_indices"] == full["reference"]["frame_indices"]
    a, f = alone["methods"]["learned_mlp"], full["methods"]["learned_mlp"]
    # the same frames through the same code; the reference is re-estimated with the same seeds
    for k in ("radiance_rel_rmse", "psnr_image_diffuse", "psnr_image_glossy"):
        assert a[k] == pytest.approx(f[k], rel=1e-9), k


def test_on_the_fly_truth_equals_the_bake(small_run: Path) -> None:
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import heldout_frames, load_compare_run

    ctx = load_compare_run(small_run)
    fs = heldout_frames(ctx, max_frames=3)
    truth = METHODS["sh_truth"]()
    truth.prepare(ctx, fs)
    got = truth.visibility(fs.batch(np.arange(fs.n_frames)))
    assert fs.baked_visibility is not None
    np.testing.assert_allclose(got, fs.baked_visibility, rtol=0, atol=1e-6)


def test_registry_accepts_a_new_method(small_run: Path) -> None:
    from prt_torch.compare import run_compare
    from prt_torch.compare.methods import FrameBatch, MethodBase, register, unregister

    @register
    class HalfTruth(MethodBase):  # a dummy: the hemisphere scaled by 0.5
        name = "half_hemisphere"
        runtime = "numpy"

        def prepare(self, run: Any, frames: Any) -> None:
            from prt_torch.scoring.lighting import unshadowed_visibility

            self.h = 0.5 * unshadowed_visibility(run.order)
            self.v = run.n_vertices

        def visibility(self, batch: FrameBatch) -> np.ndarray:
            return np.broadcast_to(self.h, (len(batch.index), self.v, self.h.shape[0]))

        def bytes(self) -> int:
            return 7

    try:
        r = run_compare(small_run, methods=["half_hemisphere", "unshadowed"], max_frames=2, image_frames=1,
                        reference_frames=0)
        assert [n for n in r["methods"] if "+peaks_" not in n] == ["sh_truth", "half_hemisphere", "unshadowed"]
        assert r["methods"]["half_hemisphere"]["bytes"] == 7
        assert r["methods"]["half_hemisphere"]["vis_rel_err"] > 0
        assert "reference" not in r
    finally:
        unregister("half_hemisphere")


def test_cli_json_and_errors(small_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compare", str(small_run), "--methods", "unshadowed,learned_mlp", "--frames", "2",
                 "--image-frames", "1", "--reference-frames", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [n for n in out["methods"] if "+peaks_" not in n] == ["sh_truth", "unshadowed", "learned_mlp"]
    assert out["frames"] == 2
    assert main(["compare", str(small_run), "--methods", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown method 'nope'" in err[0]
    assert main(["compare", str(small_run), "--clip", "moonwalk", "--frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # small_run was trained on a dataset elsewhere: one line names it, then the one error line
    run = RunDir(small_run)
    assert err[:-1] == [f"warning: {run.dataset_path} not found: reading the dataset recorded at training time, "
                        f"{run.model_meta()['dataset']}"], err
    assert err[-1].startswith("error: ") and "unknown clip 'moonwalk'" in err[-1]


def test_clip_is_posed_and_traced(small_run: Path) -> None:
    from prt_torch.compare import run_compare

    r = run_compare(small_run, methods=["learned_mlp"], clip="walk", max_frames=2, image_frames=1,
                    reference_frames=0)
    assert r["clips"] == ["walk"] and r["frames"] == 2 and "posed" in r["source"]
    assert 0 < r["methods"]["learned_mlp"]["vis_rel_err"] < 1


def test_reference_closed_forms() -> None:
    """Unoccluded vertices: constant radiance 1 gives albedo 1 for Lambert (int cos / pi = 1); a delta light of
    power E along the normal gives E / pi; an occluder above the vertex blocks the delta light."""
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.compare.reference import ReferenceLight, reference_radiance

    pos = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]])
    frames = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()  # normal +z
    faces = np.array([[0, 1, 2]])  # coplanar: occludes nothing above the plane
    eye = np.array([0.3, 0.2, 10.0])
    lam = {"lambert": builtin_brdf("lambert")}
    one = ReferenceLight(lambda d: np.ones((len(d), 3)))
    out = reference_radiance(pos, frames, faces, eye, one, lam, n_rays=4096, seed=1, offset=1e-4)["lambert"]
    np.testing.assert_allclose(out, 1.0, atol=2e-3)
    sun = ReferenceLight(lambda d: np.zeros((len(d), 3)), [(np.array([0.0, 0.0, 1.0]), np.array([2.0, 3.0, 4.0]))])
    out = reference_radiance(pos, frames, faces, eye, sun, lam, n_rays=16, seed=1, offset=1e-4)["lambert"]
    np.testing.assert_allclose(out, np.broadcast_to([2 / np.pi, 3 / np.pi, 4 / np.pi], (3, 3)), rtol=1e-9)
    # a roof over vertex 0 only
    pos2 = np.vstack([pos, [[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]]])
    frames2 = np.broadcast_to(np.eye(3), (6, 3, 3)).copy()
    faces2 = np.array([[0, 1, 2], [3, 4, 5]])
    out = reference_radiance(pos2, frames2, faces2, eye, sun, lam, n_rays=16, seed=1, offset=1e-4)["lambert"]
    assert np.all(out[0] == 0) and out[1, 0] == pytest.approx(2 / np.pi)
