"""Crowds and the vertex-order contract of the player (format /3 exports, the tiny run).

* a crowd of N characters (different clips) in ONE batched call of every graph == each character on its own;
* the fused graph runs in the cluster-sorted order, yet the player's radiance and PoseBatch fields come out in the
  ORIGINAL vertex order: equal to the split graphs' (original-order visibility.onnx + shading.onnx) and to an
  original-order Poser's;
* the CUDA provider (where onnxruntime-gpu and a GPU are present) against the CPU for the run's graphs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.player import Player
from prt_torch.player.posing import Poser
from tests.tolerance import assert_bitwise, two_path_atol


def test_crowd_batched_equals_per_character(tiny_run: Path) -> None:
    p = Player(tiny_run, brdf="phong")
    try:
        clips = list(p.character.clips)[:3] * 2  # 6 characters, 3 clips, staggered
        loc = p.crowd_locals(clips, frame=2, stagger=1)
        assert loc.shape == (6, p.character.num_joints, 4, 4)
        state, crowd = p.compute(loc)
        assert crowd.shape == (6, p.bundle.n_vertices, 3)
        # a batch of 6 and a batch of 1 run the graph's GEMMs at other shapes, which onnxruntime may give other
        # kernels (another summation order): each radiance value is the end of a float32 chain of at most
        # A (pose features) + 128 (hidden and PCA widths, <= 64 each in the tiny config) + C^2 (the RPO product)
        # + k C (the k RPO terms) roundings, of terms bounded by 4x the largest radiance (lighting and visibility
        # are smooth and mostly positive), so two batchings agree within 2 gamma_n * 4 max|radiance|
        c = p.order ** 2
        n_chain = p.bundle.n_features + 128 + c * c + p.bundle.n_terms * c
        atol = two_path_atol(n_chain, 4 * np.abs(crowd).max())
        for i in range(6):
            _, one = p.compute(loc[i:i + 1])
            np.testing.assert_allclose(crowd[i], one[0], rtol=0, atol=atol)
        assert np.abs(crowd[0] - crowd[1]).max() > 100 * atol  # different clips, different pictures
        p.crowd_chunk = 4  # calls of 4 + 2 characters: the same pictures
        np.testing.assert_allclose(p.compute(loc)[1], crowd, rtol=0, atol=atol)
        with pytest.raises(PrtError, match="at least one clip"):
            p.crowd_locals([], 0)
    finally:
        p.close()


def test_output_in_original_vertex_order(tiny_run: Path) -> None:
    fused = Player(tiny_run, brdf="phong")
    split = Player(tiny_run, brdf="phong", graph="split")
    try:
        assert fused.vertex_order is not None and fused.poser.order is not None and split.poser.order is None
        loc = fused.clip_locals("wave")[:2]
        sf, rf = fused.compute(loc)
        ss, rs = split.compute(loc)
        # split graphs run in the original order end to end: the independent reference of the contract
        np.testing.assert_allclose(rf, rs, rtol=1e-4, atol=1e-5 * np.abs(rs).max())
        for name in ("positions", "normals", "frames", "view_dirs"):
            np.testing.assert_allclose(getattr(sf, name), getattr(ss, name), rtol=1e-5, atol=1e-6)
        assert_bitwise(sf.features, ss.features, why='the same numpy operations on the same locals')
        ref = Poser(fused.character, fused.bundle.cluster, fused.bundle.cluster_axis, fused.bundle.cluster_bone)
        np.testing.assert_allclose(sf.positions_vx3(1), ref(loc, fused.eye).positions_vx3(1), rtol=1e-5, atol=1e-6)
        # the sorted arrays go to the graph as they are; assigning a field keeps the original order
        assert sf.in_order("frames", fused.vertex_order) is sf._raw["frames"]
        sf.positions = ss.positions
        assert_bitwise(sf.positions, ss.positions, why='an assigned field read back')
        assert_bitwise(sf.in_order("positions", fused.vertex_order),
                                      ss.positions[..., fused.vertex_order], why='a permutation of the same values')
        # a given visibility (original order) shades the same through either player
        vis = split.visibility(ss.features)
        np.testing.assert_allclose(fused.shade(sf, visibility=vis), split.shade(ss, visibility=vis), rtol=1e-5,
                                   atol=1e-6 * np.abs(rs).max())
    finally:
        fused.close()
        split.close()


def test_cuda_device_parity(tiny_run: Path) -> None:
    """The run's graphs (its precision) on onnxruntime's CUDA provider == on the CPU (skips without a GPU)."""
    from prt_torch.runtime.session import cuda_available

    if not cuda_available():
        with pytest.raises(PrtError, match="onnxruntime-gpu"):
            Player(tiny_run, device="cuda")
        pytest.skip("no onnxruntime CUDA provider here: needs onnxruntime-gpu and a GPU")
    try:
        gpu = Player(tiny_run, brdf="phong", device="cuda")
    except PrtError as exc:  # the provider is installed but no GPU answers
        pytest.skip(f"CUDA provider present but unusable: {exc}")
    cpu = Player(tiny_run, brdf="phong")
    try:
        loc = cpu.clip_locals("wave")[:4]
        _, want = cpu.compute(loc)
        _, got = gpu.compute(loc)
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=2e-3 * np.abs(want).max())
    finally:
        cpu.close()
        gpu.close()
