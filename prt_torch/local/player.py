"""The player-side hook of the local visibility network (:data:`prt_torch.player.sources.VISIBILITY_SOURCES`):
the neighbour-offset kernel of a run's shipped network, its input (numpy + numba, never torch)."""

from __future__ import annotations

from prt_torch.local.data import load_neighbours
from prt_torch.local.soa import LocalOffsetsSoA
from prt_torch.rundir import RunDir


def shipped_offsets(run: RunDir) -> LocalOffsetsSoA:
    """The :class:`~prt_torch.local.soa.LocalOffsetsSoA` of ``run``'s shipped neighbours (``local.npz``, one-line
    error when missing or damaged): ``positions (B, 3, V)``, ``frames (B, 9, V)`` -> ``offsets (B, 3 S, V)``, the
    input of ``local.onnx``."""
    return LocalOffsetsSoA(load_neighbours(run))
