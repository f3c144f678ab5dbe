"""The store's recorded configs, typed: the result-changing bake keys come from the BakeConfig schema's marks (the
same list and old-store defaults as before they were derived), and the dataset's configs read back validated."""

from __future__ import annotations

from pathlib import Path

import pytest

from prt_torch.bake.config import BakeConfig, absent_values, recorded_keys, result_keys
from prt_torch.bake.store import (
    RESULT_KEY_DEFAULTS,
    RESULT_KEYS,
    BakedDataset,
    below_horizon_of,
    recorded_bake_config,
    recorded_run_config,
)
from prt_torch.errors import DamagedArtifact, StaleArtifact

#: the lists as they were written by hand before the schema marks (stored attrs and resume checks depend on them)
HAND_RESULT_KEYS = ("order", "n_rays", "below_horizon", "transfer", "transfer_order", "bounces", "albedo", "seed",
                    "ray_offset", "cluster_bandwidth", "max_clusters", "min_cluster_size", "transfer_matrix",
                    "matrix_order", "matrix_bounces", "subsurface", "peaks")
HAND_DEFAULTS = {"below_horizon": "zero", "transfer_matrix": False, "matrix_order": 4, "matrix_bounces": 1,
                 "subsurface": None, "peaks": None}
HAND_PARAMS = ("order", "n_rays", "below_horizon", "transfer", "transfer_order", "bounces", "albedo", "seed",
               "ray_offset", "cluster_bandwidth", "max_clusters", "min_cluster_size", "vertex_chunk_rays",
               "transfer_matrix", "matrix_order", "matrix_bounces", "subsurface", "peaks")


def test_result_keys_come_from_the_schema() -> None:
    assert result_keys() == RESULT_KEYS == HAND_RESULT_KEYS
    assert absent_values() == RESULT_KEY_DEFAULTS == HAND_DEFAULTS
    assert recorded_keys() == HAND_PARAMS
    b = BakeConfig(transfer=True, subsurface={"sigma_a": 0.5}, cluster_bandwidth=None)
    params = b.store_params()
    assert tuple(params) == HAND_PARAMS  # the order of attrs["bake"] (the store's zarr.json bytes)
    assert params["subsurface"] == b.subsurface.model_dump(mode="json") and params["cluster_bandwidth"] is None
    assert all(params[k] == getattr(b, k) for k in HAND_PARAMS if k != "subsurface")


def _old_attrs() -> dict:
    """A store written before below_horizon, the matrix keys, subsurface and blockers were recorded."""
    bake = {k: v for k, v in BakeConfig(n_rays=64).store_params().items() if k not in HAND_DEFAULTS}
    config = {"name": "old", "character": {"fps": 24.0}, "bake": dict(bake)}
    return {"bake": {**bake, "ray_offset_world": 0.001}, "config": config}


def test_old_store_reads_with_the_old_defaults() -> None:
    attrs = _old_attrs()
    b = recorded_bake_config(attrs)
    assert b.below_horizon == below_horizon_of(attrs) == "zero"  # not today's default "one"
    assert (b.transfer_matrix, b.matrix_order, b.matrix_bounces, b.subsurface) == (False, 4, 1, None)
    assert b.n_rays == 64 and "blockers" not in b.model_fields_set
    cfg = recorded_run_config(attrs)
    assert cfg is not None and cfg.name == "old" and cfg.character.fps == 24.0 and cfg.bake == b


def test_no_recorded_config() -> None:
    assert recorded_run_config({}) is None and recorded_run_config({"config": {}}) is None
    assert recorded_run_config({"config": None}) is None
    assert recorded_bake_config({}).below_horizon == "zero"


@pytest.mark.parametrize("attrs,error,match", [
    ({"config": ["x"]}, DamagedArtifact, "recorded run config is a list, not a mapping"),
    ({"config": {"name": "x", "character": {}, "bake": {"order": 99}}}, StaleArtifact,
     r"recorded bake settings\): bad value for 'order'.*re-bake the run"),
    ({"config": {"name": "x", "character": {"what": 1}}}, StaleArtifact,
     r"recorded run config\): unknown config key 'character.what'"),
    ({"bake": {"n_rays": "many"}}, StaleArtifact, r"bad value for 'n_rays'"),
    ({"bake": ["x"]}, DamagedArtifact, "recorded bake settings are not a mapping"),
])
def test_a_recorded_config_that_does_not_validate_is_one_line(attrs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match) as exc:
        recorded_run_config(attrs, "runs/x/dataset.zarr") if "config" in attrs else recorded_bake_config(
            attrs, "runs/x/dataset.zarr")
    assert "\n" not in str(exc.value) and str(exc.value).startswith("runs/x/dataset.zarr")


def test_dataset_configs(synthetic_dataset: Path) -> None:
    ds = BakedDataset(synthetic_dataset)
    assert ds.run_config() is None  # the synthetic store records none
    assert ds.bake_config() == BakeConfig(**HAND_DEFAULTS)
