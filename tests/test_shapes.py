"""prt_torch.shapes.check_shape: exact, symbolic, ``_`` and ``*`` axes; one-line messages; numpy and torch alike."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape


@pytest.mark.parametrize("make", [np.zeros, torch.zeros], ids=["numpy", "torch"])
@pytest.mark.parametrize(("shape", "spec", "dims"), [
    ((2, 5, 3), "B V 3", {"B": 2, "V": 5}),
    ((2, 5, 3), "B, V, 3", {"B": 2, "V": 5}),
    ((2, 5, 3), ("B", "V", 3), {"B": 2, "V": 5}),
    ((4, 4), "N N", {"N": 4}),
    ((7, 3), "_ 3", {}),
    ((3,), "* 3", {}),
    ((2, 6, 3), "* 3", {}),
    ((2, 6, 3), "B *", {"B": 2}),
    ((2, 6, 9, 3), "B * 3", {"B": 2}),
    ((2, 6, 9, 3), "B ... 3", {"B": 2}),
    ((), "", {}),
    ((5, 3), ("V", -1), {"V": 5}),
    ((5, 3), (np.int64(5), np.int32(3)), {}),
])
def test_matching_shapes_return_the_symbols(make, shape, spec, dims) -> None:
    assert check_shape(make(shape), spec, name="x") == dims


@pytest.mark.parametrize("make", [np.zeros, torch.zeros], ids=["numpy", "torch"])
@pytest.mark.parametrize(("shape", "spec", "message"), [
    ((2, 5, 4), "B V 3", "positions must have shape (B, V, 3), got (2, 5, 4): axis 2 must be 3"),
    ((2, 5), "B V 3", "positions must have shape (B, V, 3), got (2, 5): must have 3 dims"),
    ((2, 5, 3, 1), "B V 3", "positions must have shape (B, V, 3), got (2, 5, 3, 1): must have 3 dims"),
    ((4, 5), "N N", "positions must have shape (N, N), got (4, 5): axis 'N' is 5 at axis 1 but 4 at axis 0"),
    ((), "* 3", "positions must have shape (..., 3), got (): must have at least 1 dims"),
    ((2, 4), "* 3", "positions must have shape (..., 3), got (2, 4): axis 1 must be 3"),
    ((5,), "3", "positions must have shape (3,), got (5,): axis 0 must be 3"),
])
def test_mismatches_raise_one_line(make, shape, spec, message) -> None:
    with pytest.raises(PrtError) as exc:
        check_shape(make(shape), spec, name="positions")
    assert str(exc.value) == message
    assert "\n" not in str(exc.value)


def test_shared_dims_bind_across_calls() -> None:
    dims: dict[str, int] = {}
    assert check_shape(np.zeros((2, 5, 3)), "B V 3", name="positions", dims=dims) is dims
    check_shape(torch.zeros(5, 3), "V 3", name="normals", dims=dims)
    assert dims == {"B": 2, "V": 5}
    with pytest.raises(PrtError, match=r"^weights must have shape \(V, J\), got \(6, 2\): axis 'V' is 6 at axis 0 "
                                       r"but 5 in an earlier input$"):
        check_shape(np.zeros((6, 2)), "V J", name="weights", dims=dims)


def test_not_an_array() -> None:
    with pytest.raises(PrtError, match=r"^x must have shape \(3,\), got list \(not an array\)$"):
        check_shape([1, 2, 3], "3", name="x")


@pytest.mark.parametrize("spec", ["B * * 3", "B * ... 3", "B 3.5", "B-1"])
def test_bad_specs_are_programming_errors(spec) -> None:
    with pytest.raises(ValueError) as exc:
        check_shape(np.zeros((1, 2, 3)), spec)
    assert not isinstance(exc.value, PrtError)


@given(st.lists(st.integers(0, 6), max_size=5), st.lists(st.sampled_from(["int", "sym", "_"]), max_size=5))
def test_property_exact_and_symbolic(shape, kinds) -> None:
    """A spec built from the shape itself always matches; any one exact axis changed always fails, one line."""
    kinds = (kinds + ["int"] * len(shape))[: len(shape)]
    pairs = list(enumerate(zip(shape, kinds, strict=True)))
    spec = [s if k == "int" else (f"S{i}" if k == "sym" else "_") for i, (s, k) in pairs]
    assert check_shape(np.zeros(shape), spec) == {f"S{i}": s for i, (s, k) in pairs if k == "sym"}
    for i, k in enumerate(kinds):
        if k == "int":
            bad = list(shape)
            bad[i] += 1
            with pytest.raises(PrtError, match=f"axis {i} must be {shape[i]}$") as exc:
                check_shape(np.zeros(bad), spec)
            assert "\n" not in str(exc.value)
    with pytest.raises(PrtError, match=f"must have {len(shape)} dims$"):
        check_shape(np.zeros([*shape, 1]), spec)


def test_does_not_import_torch() -> None:
    code = "import sys, numpy\nfrom prt_torch.shapes import check_shape\ncheck_shape(numpy.zeros(3), '3')\n" \
           "assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
