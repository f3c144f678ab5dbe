"""``prt play --renderer transfer``: seed 000's learned transfer as a ``prt play`` renderer (the hook of
:data:`prt_torch.player.renderers.RENDERERS`).

Light on purpose (``prt --help`` imports it to build the ``prt play`` parser): the player
(:class:`~prt_torch.transfer.player.TransferPlayer`) is imported inside :func:`build` only.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from prt_torch.player.renderers import Renderer

if TYPE_CHECKING:
    from prt_torch.transfer.player import TransferPlayer


def build(args: argparse.Namespace, size: tuple[int, int]) -> TransferPlayer:
    """The :class:`~prt_torch.transfer.player.TransferPlayer` of ``args.run`` (its exported transfer graph),
    rendering ``size`` ``(H, W)`` images."""
    from prt_torch.transfer.player import TransferPlayer

    return TransferPlayer(args.run, env=args.env, brdf=args.brdf, threads=args.threads, window_size=size,
                          device=args.device)


#: ``--renderer transfer``
TRANSFER = Renderer(names=("transfer",), help="transfer: the run's learned diffuse (+ subsurface) transfer, L . t "
                                              "(seed 000, train.transfer, then prt export)", build=build)
