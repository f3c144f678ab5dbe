"""``prt compare --methods s001,posespace`` on the tiny seed-001 run (tests/fixtures_s001.py): the eq. 9 player
against eq. 5 (:func:`shade_matrix` of the interpolated matrices), error bounds against the baked matrices, the
compression ratio, availability."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError


@pytest.fixture(scope="module")
def compared(s001_run: tuple[Path, Path]) -> dict:
    from prt_torch.cli import main
    from prt_torch.rundir import RunDir

    run = s001_run[1]
    assert main(["compare", str(run), "--methods", "s001,posespace", "--frames", "4", "--image-frames", "1",
                 "--reference-frames", "0"]) == 0
    return json.loads(RunDir(run).compare_json.read_text())


def test_entries_and_error_bounds(compared: dict, s001_run: tuple[Path, Path]) -> None:
    from prt_torch.rundir import RunDir
    from prt_torch.s001.posespace import CompressedTransfer

    data = CompressedTransfer.load(RunDir(s001_run[1]).s001)
    for name in ("s001", "posespace"):
        m = compared["methods"][name]
        assert m["output"] == "radiance" and m["vis_rel_err"] is None and m["ms_per_frame"] > 0
        assert m["bytes"] == data.stored_bytes() and m["compression_ratio"] == pytest.approx(
            data.meta["raw_bytes"] / data.stored_bytes())
        # against the baked matrices of the compared rows: well below a total miss (1.0), and the radiance error of
        # shading them is of the same size (eq. 5 is linear in T)
        assert 0 < m["transfer_rel_err"] < 0.5 and 0 < m["matrix_radiance_rel_rmse"] < 0.5
        assert np.isfinite(m["radiance_rel_rmse"]) and np.isfinite(m["psnr_image_diffuse"])


def test_player_eq9_equals_eq5_on_the_interpolated_matrices(s001_run: tuple[Path, Path]) -> None:
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.rundir import RunDir
    from prt_torch.s001.brdf_matrix import brdf_matrix, factor
    from prt_torch.s001.player import S001Player
    from prt_torch.s001.posespace import CompressedTransfer
    from prt_torch.s001.shading import shade_matrix

    rd = RunDir(s001_run[1])
    data = CompressedTransfer.load(rd.s001)
    ds = rd.dataset()
    row = ds.split_rows("heldout")[2:3]
    t = ds.rows(row, ("pose", "frames", "positions"))
    c = data.n_coeffs
    light = np.random.default_rng(0).normal(size=(c, 3))
    eye = np.array([0.3, -3.0, 1.2])
    hg = {n: factor(brdf_matrix(builtin_brdf(n), int(round(c**0.5))), 4) for n in ("lambert", "phong")}
    view = eye - t["positions"][0].astype(np.float64)
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    for scheme in ("s001", "posespace"):
        p = S001Player(data, scheme)  # type: ignore[arg-type]
        p.set_shading(hg, light)
        got = p.radiance(t["pose"][0], t["frames"][0], t["positions"][0], eye)
        tm = p.transfer(t["pose"][0], t["frames"][0]).astype(np.float64)
        for n, (h, g) in hg.items():
            ref = shade_matrix(tm, light, t["frames"][0].astype(np.float64), view, h, g)
            np.testing.assert_allclose(got[n], ref, rtol=1e-3, atol=1e-4 * np.abs(ref).max())


def test_not_available_without_s001_npz(s001_run: tuple[Path, Path], tmp_path: Path) -> None:
    from prt_torch.compare.methods import resolve
    from prt_torch.compare.run import load_compare_run
    from prt_torch.rundir import RunDir

    ctx = load_compare_run(s001_run[1])
    assert "s001" in resolve(None, ctx) and "posespace" in resolve(None, ctx)
    path = RunDir(s001_run[1]).s001
    moved = tmp_path / "s001.npz"
    path.rename(moved)
    try:
        assert "s001" not in resolve(None, ctx)
        with pytest.raises(PrtError, match="not available") as e:
            resolve(["s001"], ctx)
        assert "\n" not in str(e.value)
    finally:
        moved.rename(path)
