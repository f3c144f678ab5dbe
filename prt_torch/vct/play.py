"""``prt play --renderer sg``: seed 004's renderer as a ``prt play`` renderer (the hook of
:data:`prt_torch.player.renderers.RENDERERS`).

Light on purpose (``prt --help`` imports it to build the ``prt play`` parser): :class:`~prt_torch.vct.player.SGPlayer`,
and with it torch and healpy, is imported inside :func:`build` only.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from prt_torch import limits
from prt_torch.player.renderers import Renderer

if TYPE_CHECKING:
    from prt_torch.vct.player import SGPlayer


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--vct-resolution``: the voxel grid side."""
    parser.add_argument("--vct-resolution", type=int, default=128, help="--renderer sg: voxel grid side (64-256)")


def build(args: argparse.Namespace, size: tuple[int, int]) -> SGPlayer:
    """``--vct-resolution`` checked (16..512), then the :class:`~prt_torch.vct.player.SGPlayer` of ``args.run``
    rendering ``size`` ``(H, W)`` images."""
    from prt_torch.vct.player import SGPlayer

    limits.check_int(args.vct_resolution, "--vct-resolution", 16, 512)
    return SGPlayer(args.run, env=args.env, brdf=args.brdf, threads=args.threads, window_size=size,
                    resolution=args.vct_resolution, device=args.device)


#: ``--renderer sg``
SG = Renderer(names=("sg",), help="sg: SG lighting + voxel cone-traced visibility of each posed frame (seed 004; "
                                  "needs torch and healpy)", build=build, add_arguments=add_arguments)
