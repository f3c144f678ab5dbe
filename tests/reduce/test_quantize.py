"""16-bit quantization: error bound per entry, full code range, bytes, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.s001.quantize import dequantize16, quantize16, quantized_nbytes
from tests.tolerance import assert_bitwise


def test_error_at_most_half_a_step_per_column_and_group() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5000, 8)) * rng.uniform(0.01, 100.0, 8) + rng.normal(size=8) * 50
    groups = rng.integers(0, 7, 5000)
    for g in (None, groups):
        codes, scale, offset = quantize16(x.astype(np.float32), g)
        assert codes.dtype == np.uint16
        back = dequantize16(codes, scale, offset, g).astype(np.float64)
        gi = np.zeros(len(x), dtype=int) if g is None else g
        step = scale.astype(np.float64)[gi]
        err = np.abs(back - x.astype(np.float32))
        # scale/2 from rounding, plus float32 rounding of the decoded value (half an ulp of |x|)
        assert np.all(err <= step / 2 + np.spacing(np.abs(x).astype(np.float32)))
        for k in range(scale.shape[0]):  # the range of each column (group) is the full code range
            sel = gi == k
            assert codes[sel].min(axis=0).tolist() == [0] * 8 and codes[sel].max(axis=0).tolist() == [65535] * 8
        np.testing.assert_allclose(scale.astype(np.float64)[0] * 65535,
                                   np.ptp(x[gi == 0].astype(np.float32), axis=0), rtol=1e-6)


def test_constant_column_exact_and_bytes() -> None:
    x = np.column_stack([np.full(10, 3.25), np.linspace(-1, 1, 10)]).astype(np.float32)
    codes, scale, offset = quantize16(x)
    assert scale[0, 0] == 0.0
    assert_bitwise(dequantize16(codes, scale, offset)[:, 0], x[:, 0],
                   why='a constant column decodes to its offset exactly (zero scale)')
    assert quantized_nbytes(1000, 8, 10) == 2 * 8000 + 8 * 80


@pytest.mark.parametrize("x, groups, match", [
    (np.zeros(5), None, r"\(N, M\)"),
    (np.array([[1.0, np.nan]]), None, "NaN"),
    (np.zeros((4, 2)), np.zeros(3, dtype=int), "groups must have shape"),
    (np.zeros((4, 2)), np.zeros(4), "integers"),
])
def test_bad_inputs_raise_one_line_errors(x: np.ndarray, groups, match: str) -> None:
    with pytest.raises(PrtError, match=match) as e:
        quantize16(x, groups)
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="scale"):
        dequantize16(np.zeros((3, 2), dtype=np.uint16), np.zeros((1, 3)), np.zeros((1, 3)))
