"""``prt compare`` method ``sg_vct`` (seed 004: SG lighting + voxel cone tracing) on ``small_run``, against the
Monte-Carlo Embree reference under a small bright sun; the ``--light`` options."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.cli import main

pytest.importorskip("healpy")


@pytest.fixture(scope="module")
def sun_compare(small_run: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from prt_torch.compare import run_compare

    return run_compare(small_run, methods=["sg_vct", "sg_vct_nopeak"], light="sun", max_frames=1, image_frames=1,
                       reference_frames=1, reference_rays=96)


def test_sg_vct_under_a_sun_vs_the_reference(sun_compare: dict[str, Any]) -> None:
    r = sun_compare
    assert [n for n in r["methods"] if "+peaks_" not in n] == ["sh_truth", "sg_vct", "sg_vct_nopeak"]
    assert r["light"] == "sun"
    assert "sun disk" in r["reference"]["lighting"]
    sg, truth = r["methods"]["sg_vct"], r["methods"]["sh_truth"]
    assert sg["output"] == "radiance" and sg["vis_rel_err"] is None and sg["ms_per_frame"] > 0
    assert sg["sg_peaks"] == 1 and len(sg["ms_voxelize_trace_shade"]) == 3  # the sun is found; timed parts
    for m in (sg, r["methods"]["sg_vct_nopeak"]):
        ref = m["vs_reference"]
        assert np.isfinite(ref["psnr_image_diffuse"]) and np.isfinite(ref["psnr_image_glossy"])
    # the order-4 SH truth cannot hold a 2-degree sun; the SG lighting with cone-traced shadows can: closer to
    # the full-resolution Monte-Carlo reference per vertex
    assert sg["vs_reference"]["radiance_rel_rmse"] < truth["vs_reference"]["radiance_rel_rmse"]
    assert sg["vs_reference"]["radiance_rel_rmse"] < 0.35


def test_sg_vct_is_opt_in(small_run: Path) -> None:
    from prt_torch.compare.methods import resolve
    from prt_torch.compare.run import load_compare_run

    ctx = load_compare_run(small_run)
    default = resolve(None, ctx)
    assert "sg_vct" not in default and "sg_vct_nopeak" not in default
    assert resolve(["sg_vct"], ctx) == ["sh_truth", "sg_vct"]


def test_light_options_are_checked(small_run: Path) -> None:
    assert main(["compare", str(small_run), "--sun-size", "2", "--frames", "1"]) == 2  # needs --light sun
    assert main(["compare", str(small_run), "--light", "sun", "--sun-size", "90", "--frames", "1"]) == 2
    with pytest.raises(SystemExit) as e:  # argparse: not one of sky, smooth, sun
        main(["compare", str(small_run), "--light", "moon"])
    assert e.value.code == 2
