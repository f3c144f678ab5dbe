"""Tolerances derived from the arithmetic, for comparing two floating-point paths (docs/DESIGN.md, determinism).

Two paths that run the same operations in the same order on the same data are compared for equality. Two that
do not - a GEMM of another shape (onnxruntime's MLAS, MKL and OpenBLAS pick kernels by shape, CPU and thread
count), a batch instead of one item, another vertex order, another CPU kernel - are compared with the standard
forward-error bound of a float sum (Higham, *Accuracy and Stability of Numerical Algorithms*, eq. 3.5): a sum of
``n`` products computed in any order is within ``gamma_n * sum |a_i b_i|`` of the exact one, with
``gamma_n = n u / (1 - n u)`` and ``u`` the unit round-off (2^-24 in float32). Two such paths are within twice
that of each other.
"""

from __future__ import annotations

import numpy as np


def unit_roundoff(dtype: type | np.dtype = np.float32) -> float:
    """``u = eps / 2``: the largest relative error of one rounding (2^-24 for float32, 2^-53 for float64)."""
    return float(np.finfo(dtype).eps) / 2


def gamma(n: int, dtype: type | np.dtype = np.float32) -> float:
    """``gamma_n = n u / (1 - n u)``: the relative error bound of a chain of ``n`` roundings."""
    nu = n * unit_roundoff(dtype)
    assert nu < 1, f"gamma_{n} undefined in {np.dtype(dtype)}"
    return nu / (1 - nu)


def two_path_atol(n_roundings: int, magnitude: float, dtype: type | np.dtype = np.float32) -> float:
    """Absolute tolerance between two paths that each compute a value with at most ``n_roundings`` roundings
    along its longest chain (sums of products and elementwise ops) whose terms are bounded by ``magnitude``
    (the sum of the absolute values of the terms, or an upper bound of it): ``2 gamma_n magnitude``."""
    return 2 * gamma(n_roundings, dtype) * float(magnitude)


def _floating(x: object) -> bool:
    a = np.asarray(x)
    return np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.complexfloating)


def assert_bitwise(actual: object, desired: object, why: str, err_msg: str = "") -> None:
    """Floating-point arrays equal bit for bit - allowed only where the same operations run in the same order on
    the same data (``why`` says which: a save/load round trip, the same seeded call twice, a copy, a value exact by
    construction). Two different paths are compared with :func:`two_path_atol` instead: the suite's conftest
    makes ``np.testing.assert_array_equal`` refuse floating-point arrays, so every exact comparison says why."""
    assert why.strip(), "assert_bitwise needs the reason equality holds"
    _EXACT_ASSERT(actual, desired, err_msg=err_msg or why)


#: numpy's own assert_array_equal (the conftest replaces the public one by :func:`checked_assert_array_equal`)
_EXACT_ASSERT = np.testing.assert_array_equal


def checked_assert_array_equal(actual: object, desired: object, *args: object, **kwargs: object) -> None:
    """``np.testing.assert_array_equal`` for integers, booleans and strings; floating-point arrays are refused
    (one line naming :func:`assert_bitwise` and :func:`two_path_atol`)."""
    if _floating(actual) or _floating(desired):
        raise AssertionError("assert_array_equal on floating-point arrays: use tests.tolerance.assert_bitwise(a, b, "
                             "why=...) where the same operations run in the same order on the same data, else "
                             "assert_allclose with tests.tolerance.two_path_atol (docs/DESIGN.md, determinism)")
    _EXACT_ASSERT(actual, desired, *args, **kwargs)
