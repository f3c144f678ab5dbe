"""``prt play --renderer s001 | posespace``: seed 001's compressed transfer matrices as a ``prt play`` renderer (the
hook of :data:`prt_torch.player.renderers.RENDERERS`).

Light on purpose (``prt --help`` imports it to build the ``prt play`` parser): the player
(:class:`~prt_torch.s001.renderer.S001RunPlayer`) is imported inside :func:`build` only.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from prt_torch.player.renderers import Renderer

if TYPE_CHECKING:
    from prt_torch.s001.renderer import S001RunPlayer


def build(args: argparse.Namespace, size: tuple[int, int]) -> S001RunPlayer:
    """The :class:`~prt_torch.s001.renderer.S001RunPlayer` of ``args.run`` with the scheme ``args.renderer``
    (``s001``: per segment, ``posespace``: globally), rendering ``size`` ``(H, W)`` images."""
    from prt_torch.s001.renderer import S001RunPlayer

    return S001RunPlayer(args.run, env=args.env, brdf=args.brdf, scheme=args.renderer, window_size=size)


#: ``--renderer s001`` / ``--renderer posespace``
S001 = Renderer(names=("s001", "posespace"), help="s001 / posespace: the run's compressed transfer matrices (seed "
                                                  "001, train.s001) interpolated per segment / globally", build=build)
