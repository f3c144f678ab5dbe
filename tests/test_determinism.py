"""The determinism policy (docs/DESIGN.md, "Determinism"), enforced.

* Fixed-order arithmetic (``prt_torch.exact``) equals a sequential numpy reference bit for bit (the same
  operations in the same order) and ``np.matmul`` within the two-path bound of the float sum.
* The bake is bit-exact across machines: ``prt bake`` with other BLAS kernels (``OPENBLAS_CORETYPE``), another
  numpy SIMD level (``NPY_DISABLE_CPU_FEATURES``, as on a CPU without AVX-512) and the libraries' own kernel
  choice (``PRT_KERNELS=native``) writes the same bits as a default bake.
* Fits: ``prt train`` pins the BLAS / ATen kernels before they load (``prt_torch.kernels``), so the same fit
  comes out whatever kernel the machine's environment asks for, and ``model.json`` says it was pinned.
* The suite refuses ``assert_array_equal`` on floating-point arrays (tests/conftest.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
import zarr

from prt_torch.exact import fixed_order_matmul, small_matmul
from tests.tolerance import assert_bitwise, two_path_atol

REPO = Path(__file__).resolve().parents[1]

#: numpy's AVX-512 dispatch targets: disabled, numpy runs the AVX2 loops an AVX2-only machine runs
NO_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"

#: what another machine's environment can look like: another OpenBLAS kernel, no AVX-512 in numpy
OTHER_MACHINE = {"OPENBLAS_CORETYPE": "Nehalem", "OPENBLAS_L2_SIZE": "256", "NPY_DISABLE_CPU_FEATURES": NO_AVX512,
                 "ATEN_CPU_CAPABILITY": "default", "OMP_NUM_THREADS": "2"}

#: a small bake: the built-in character's clips only (no random poses: every input is FK of the clips)
CONFIG = {
    "name": "det",
    "character": {"source": "builtin", "density": 0.08, "fps": 5, "train_clips": ["walk", "squat"],
                  "heldout_clips": ["wave"], "random_poses": 0, "seed": 0},
    "bake": {"order": 4, "n_rays": 48, "frames_per_task": 8, "workers": 1, "seed": 0},
    "train": {"kinds": ["linear", "mlp"], "default_kind": "mlp", "alphas": [0.01, 1.0], "mlp_alphas": [0.1],
              "neurons": [6], "folds": 2, "cv_iter": 10, "max_iter": 80, "seed": 0},
}


def _clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY",
                        "MKL_CBWR", "PRT_KERNELS", "OMP_NUM_THREADS")}
    return {**env, **extra}


def _prt(env: dict[str, str], *args: str) -> None:
    r = subprocess.run([sys.executable, "-m", "prt_torch", *args], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]


def _config(tmp: Path, name: str, cfg: dict | None = None) -> Path:
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump({**(cfg or CONFIG), "run_dir": str(tmp / name)}))
    return path


def _arrays(store: Path) -> dict[str, np.ndarray]:
    g = zarr.open_group(str(store), mode="r")
    return {name: np.asarray(a[:]) for name, a in g.arrays()}


def test_fixed_order_matmul_is_the_sequential_sum_and_close_to_blas() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(2, 5, 37)).astype(np.float32)
    b = rng.normal(size=(37, 23)).astype(np.float32)
    got = fixed_order_matmul(a, b)
    ref = np.zeros((2, 5, 23), np.float32)  # the same operations in the same order, in numpy float32
    for k in range(37):
        ref = ref + a[..., k:k + 1] * b[k]
    assert_bitwise(got, ref, why="the same products and sums in the same order (no fused multiply-add)")
    scale = np.abs(a) @ np.abs(b)  # sum |a_k b_k| per entry: the bound of the float sum (any order)
    assert np.all(np.abs(got - a @ b) <= two_path_atol(37, 1.0) * scale)
    with pytest.raises(ValueError, match="do not chain"):
        fixed_order_matmul(a, b.T)
    m = rng.normal(size=(3, 4, 4))
    n = rng.normal(size=(4, 4))
    want = m[..., :, 0:1] * n[0:1, :] + m[..., :, 1:2] * n[1:2, :] + m[..., :, 2:3] * n[2:3, :] \
        + m[..., :, 3:4] * n[3:4, :]
    assert_bitwise(small_matmul(m, n), want, why="the same four products and three sums in the same order")
    np.testing.assert_allclose(small_matmul(m, n), m @ n, rtol=0, atol=two_path_atol(4, np.abs(m).max() * 4, np.float64)
                               * np.abs(n).max())


def test_the_bake_is_bit_exact_across_blas_kernels_and_simd_levels(tmp_path: Path) -> None:
    _prt(_clean_env(), "bake", str(_config(tmp_path, "here")), "--no-progress")
    _prt(_clean_env(**OTHER_MACHINE, PRT_KERNELS="native"), "bake", str(_config(tmp_path, "there")), "--no-progress")
    here, there = _arrays(tmp_path / "here" / "dataset.zarr"), _arrays(tmp_path / "there" / "dataset.zarr")
    assert set(here) == set(there) and {"visibility", "positions", "frames", "pose"} <= set(here)
    for name in here:
        assert_bitwise(there[name], here[name], err_msg=name,
                       why="the bake's arithmetic is fixed-order (prt_torch.exact): no kernel choice enters it")


def test_prt_train_pins_the_kernels_and_fits_the_same_under_another_environment(tmp_path: Path) -> None:
    base = _config(tmp_path, "base")
    _prt(_clean_env(), "bake", str(base), "--no-progress")
    runs = {}
    for name, env in (("here", _clean_env()), ("there", _clean_env(**OTHER_MACHINE))):
        cfg = _config(tmp_path, name)
        (tmp_path / name).mkdir()
        subprocess.run(["cp", "-r", str(tmp_path / "base" / "dataset.zarr"), str(tmp_path / name)], check=True)
        _prt(env, "train", str(cfg))
        runs[name] = tmp_path / name
    for name, run in runs.items():
        assert json.loads((run / "model.json").read_text())["blas_kernels"] == "pinned", name
    import torch

    for kind in ("linear", "mlp"):
        a = torch.load(runs["here"] / "models" / f"{kind}.pt", weights_only=False)
        b = torch.load(runs["there"] / "models" / f"{kind}.pt", weights_only=False)
        ta = {k: v for k, v in _tensors(a)}
        tb = {k: v for k, v in _tensors(b)}
        assert ta.keys() == tb.keys() and ta
        for k in ta:
            assert_bitwise(tb[k].numpy(), ta[k].numpy(), err_msg=f"{kind} {k}",
                           why="the same fit with the same pinned kernels and one thread")


def _tensors(obj: object, prefix: str = ""):
    import torch

    if isinstance(obj, torch.Tensor):
        yield prefix, obj.detach().cpu()
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _tensors(v, f"{prefix}.{k}")
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _tensors(v, f"{prefix}[{i}]")


def test_float_arrays_need_a_reason_to_be_compared_exactly() -> None:
    np.testing.assert_array_equal(np.arange(3), [0, 1, 2])  # integers: as numpy does
    with pytest.raises(AssertionError, match="assert_bitwise"):
        np.testing.assert_array_equal(np.zeros(3), np.zeros(3))
    with pytest.raises(AssertionError, match="reason"):
        assert_bitwise(np.zeros(3), np.zeros(3), why=" ")
