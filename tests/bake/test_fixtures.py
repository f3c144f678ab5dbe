"""The ``small_dataset`` session fixture keeps the contract its docstring promises to the other test suites."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prt_torch.bake.store import open_dataset
from prt_torch.rig.vertex_frames import vertex_frames


def test_small_dataset_contract(small_dataset: Path) -> None:
    ds = open_dataset(small_dataset)
    assert Path(small_dataset).name == "dataset.zarr" and ds.complete
    assert ds.clip_names == ["stretch", "random", "wave"]
    assert ds.splits == {"train": ["stretch", "random"], "heldout": ["wave"]}
    assert int(ds.train_mask.sum()) == 101 and int(ds.heldout_mask.sum()) == 31
    assert ds.sh_order == 4 and ds.n_rays == 128 and ds.visibility.shape[2] == 16
    assert 2000 <= ds.n_vertices <= 4000 and ds.pose.shape == (132, 120)
    dc = ds.visibility[..., 0]
    assert 0 <= dc.min() and dc.max() <= 2 * math.pi / math.sqrt(4 * math.pi) + 1e-5
    assert dc.mean() > 1.0  # mostly open surface, with real occlusion somewhere
    assert (dc < 1.0).mean() > 0.01
    # the stored frames are what bake.frames rebuilds from the stored clusters (the player's path)
    ch = ds.character()
    poses = ch.pose("wave", fps=10.0)
    _, nrm = ch.skin_mesh(poses)
    rebuilt = vertex_frames(nrm, poses.skin, ds.cluster, ds.cluster_axis, ds.cluster_bone)
    np.testing.assert_allclose(rebuilt, ds.frames[ds.heldout_mask], atol=1e-5)
