"""Visibility sources of deformable subjects: the shipped networks a deformable player can run instead of the
per-cluster model (:data:`VISIBILITY_SOURCES`).

A run ships such a network under an ``export.json`` entry named after its method package (``local``: the local
visibility network of :mod:`prt_torch.local`, ``local.onnx`` + ``local.npz``). The network itself runs in
onnxruntime (:class:`~prt_torch.runtime.session.OrtGraph`, opened by the player); its input is computed on the CPU
from the posed positions and vertex frames by the package's hook: ``hook(run) -> NetworkInput``, reading what the
run ships for it. A player asks :func:`network_input`; nothing here imports a method package.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.plugins import StageTable, load

if TYPE_CHECKING:
    from prt_torch.rundir import RunDir


class NetworkInput(Protocol):
    """The input of a shipped visibility network: ``positions (B, 3, V)``, ``frames (B, 9, V)`` float32
    (vertex-last; entry ``3 k + c`` of the frames is ``F[k, c]``, rows t, b, n) -> ``(B, F, V)`` float32, the
    network's ``offsets`` input; ``n_vertices``: the ``V`` it was shipped for."""

    n_vertices: int

    def __call__(self, positions_soa: np.ndarray, frames_soa: np.ndarray) -> np.ndarray: ...


#: method package -> the hook building the input of the visibility network it ships (``hook(run) -> NetworkInput``)
VISIBILITY_SOURCES: StageTable = {
    "local": ("prt_torch.local.player:shipped_offsets",),
    "s001": (),
    "transfer": (),
    "shexp": (),
    "vct": (),
    "heightfield": (),
    "cloth": (),
}


def network_input(package: str, run: RunDir) -> NetworkInput:
    """The input computation of the network ``run`` ships under the ``export.json`` entry ``package``."""
    refs = VISIBILITY_SOURCES.get(package, ())
    if len(refs) != 1:
        raise PrtError(f"no shipped visibility network of {package!r} a player can run: expected one of "
                       f"{', '.join(p for p, r in VISIBILITY_SOURCES.items() if r)}")
    return load(refs[0])(run)
