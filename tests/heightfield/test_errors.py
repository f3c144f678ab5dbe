"""Bad input: one-line PrtErrors."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.heightfield.horizon import horizon_angles
from prt_torch.heightfield.surface import Waves, grid_faces, grid_frames, make_frame
from prt_torch.heightfield.visibility import HeightFieldVisibility
from prt_torch.heightfield.wedges import WedgeTable


def _one_line(exc: pytest.ExceptionInfo[PrtError], *words: str) -> None:
    msg = str(exc.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_bad_heights() -> None:
    model = HeightFieldVisibility(3, 4)
    good = np.zeros((8, 8))
    frames = grid_frames(good)
    nan = good.copy()
    nan[3, 4] = np.nan
    with pytest.raises(PrtError) as e:
        model(nan, frames)
    _one_line(e, "NaN")
    with pytest.raises(PrtError) as e:
        make_frame(nan)
    _one_line(e, "NaN")
    for bad in (np.zeros((8, 9)), np.zeros(64), np.zeros((2, 8, 8))):
        with pytest.raises(PrtError) as e:
            model(bad, frames)
        _one_line(e, "square")
    with pytest.raises(PrtError) as e:
        model(good, frames[:-1])
    _one_line(e, "frames")
    with pytest.raises(PrtError) as e:
        horizon_angles(np.zeros((3, 3)), 4)
    _one_line(e, "too small")
    with pytest.raises(PrtError) as e:
        grid_faces(2)
    _one_line(e, "grid size")
    with pytest.raises(PrtError) as e:
        horizon_angles(good, 4, extent=-1.0)
    _one_line(e, "extent")


@pytest.mark.parametrize("n_wedges", [0, -3, 2.5])
def test_bad_wedges(n_wedges) -> None:
    for make in (lambda: HeightFieldVisibility(4, n_wedges), lambda: WedgeTable.make(4, n_wedges),
                 lambda: horizon_angles(np.zeros((8, 8)), n_wedges)):
        with pytest.raises(PrtError) as e:
            make()
        _one_line(e, "wedges")


def test_bad_settings() -> None:
    with pytest.raises(PrtError) as e:
        HeightFieldVisibility(4, 8, stride=0)
    _one_line(e, "stride")
    with pytest.raises(PrtError) as e:
        HeightFieldVisibility(4, 8, below_horizon="maybe")
    _one_line(e, "below_horizon")
    with pytest.raises(PrtError) as e:
        Waves(3)
    _one_line(e, "grid size")
