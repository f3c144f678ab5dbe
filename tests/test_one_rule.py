"""One definition per convention (issue 26): the below-horizon options, "is this run deformable", PSNR, evenly
spaced indices, the recorded config and the progress bar each have one owner that every caller uses."""

from __future__ import annotations

import typing
from pathlib import Path

import numpy as np
import pytest

from prt_torch.conventions import BELOW_HORIZON, BelowHorizon


def test_below_horizon_one_definition() -> None:
    from prt_torch.bake.config import BakeConfig
    from prt_torch.bake.store import VISIBILITY_CONVENTIONS
    from prt_torch.bake.trace import check_below_horizon
    from prt_torch.shexp.visibility import BELOW_HORIZON as SHEXP

    assert typing.get_args(BelowHorizon) == BELOW_HORIZON == ("zero", "one")
    assert set(VISIBILITY_CONVENTIONS) == set(BELOW_HORIZON) and SHEXP == (None, *BELOW_HORIZON)
    assert all(check_below_horizon(v) == v for v in BELOW_HORIZON)
    with pytest.raises(ValueError, match="below_horizon"):
        BakeConfig(below_horizon="half")


def test_psnr_one_rule() -> None:
    from prt_torch.metrics import psnr, psnr_from_mse
    from prt_torch.scoring.statistics import ImageStats, RadianceStats

    assert psnr_from_mse(0.0) == float("inf") and psnr_from_mse(0.01) == pytest.approx(20.0)
    assert psnr_from_mse(0.01, 2.0) == pytest.approx(10 * np.log10(4 / 0.01))
    t = np.array([[1.0, 2.0], [0.5, -1.0]])
    p = t + 0.1
    stats = RadianceStats()
    stats.add(p, t)
    assert stats.psnr == psnr(p, t)
    img = ImageStats()
    img.add(0.04, 4)
    assert img.psnr == psnr_from_mse(0.01)


def test_evenly_spaced_indices() -> None:
    from prt_torch.metrics import evenly_spaced_indices
    from prt_torch.scoring.sampling import evenly_spaced

    assert evenly_spaced_indices(10, 4).tolist() == [0, 3, 6, 9]
    assert evenly_spaced_indices(5, 5).tolist() == list(range(5))
    assert evenly_spaced_indices(3, 0).size == 0 and evenly_spaced_indices(0, 0).dtype == np.int64
    assert evenly_spaced(10, 4).tolist() == [0, 3, 6, 9] and evenly_spaced(3, 10).tolist() == [0, 1, 2]


def test_recorded_config_and_deformable(synthetic_dataset: Path, tmp_path: Path) -> None:
    from prt_torch.bake.deformable import is_deformable
    from prt_torch.bake.store import BakedDataset, recorded_config
    from prt_torch.export.run import dataset_is_deformable as run_is_deformable
    from prt_torch.rundir import RunDir

    ds = BakedDataset(synthetic_dataset)
    assert ds.recorded_config() == {} and ds.recorded_fps() is None
    assert recorded_config({}) == {} and recorded_config({"config": None}) == {}
    assert recorded_config({"config": {"character": {"fps": 24}}}) == {"character": {"fps": 24}}
    assert not is_deformable(ds.attrs)
    assert is_deformable({"deformable": True}) and is_deformable({"config": {"cloth": {"kind": "cape"}}})
    assert not run_is_deformable(RunDir(tmp_path))  # no dataset: not deformable


def test_progress_bar_columns() -> None:
    pytest.importorskip("rich")
    from prt_torch.progress import progress_bar

    def names(p: object) -> list[str]:
        return [type(c).__name__ + (f":{c.text_format}" if hasattr(c, "text_format") else "")
                for c in p.columns]  # type: ignore[attr-defined]

    assert names(progress_bar("bake ({task.fields[backend]})", ("frames", "{task.fields[rate]}"),
                              remaining=True)) == [
        "TextColumn:bake ({task.fields[backend]})", "BarColumn", "MofNCompleteColumn", "TextColumn:frames",
        "TextColumn:{task.fields[rate]}", "TimeElapsedColumn", "TimeRemainingColumn"]
    assert names(progress_bar(elapsed=False, remaining=True)) == [
        "TextColumn:{task.description}", "BarColumn", "MofNCompleteColumn", "TimeRemainingColumn"]
    assert names(progress_bar(counted=False, spinner=True, transient=True)) == [
        "SpinnerColumn", "TextColumn:{task.description}", "TimeElapsedColumn"]
