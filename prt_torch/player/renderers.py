"""The renderers ``prt play --renderer`` offers: the player's own (``onnx``) and the method packages'
(:data:`RENDERERS`).

A renderer is a :class:`Renderer`: the ``--renderer`` value(s) it answers to, its part of the option's help, the
options it adds to ``prt play`` (``add_arguments``, optional) and ``build(args, size)``, which checks those options
and returns the :class:`~prt_torch.player.player.Player` (or subclass) that plays the run. ``prt play``
(:mod:`prt_torch.commands.play`) takes its ``--renderer`` choices, help and options from :func:`renderers` and
constructs the chosen one with :func:`renderer`; nothing here imports a method package (the table's references are
resolved by :mod:`prt_torch.plugins` when the parser is built).

A method package's hook module (``prt_torch.<package>.play``) must stay light: ``prt --help`` builds the ``prt
play`` parser, so it imports the hook modules; the player classes are imported inside ``build``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from prt_torch.errors import PrtError
from prt_torch.plugins import StageTable, hooks

if TYPE_CHECKING:
    from prt_torch.player.player import Player


@dataclass(frozen=True)
class Renderer:
    """One ``--renderer`` entry of ``prt play``.

    ``names``: the ``--renderer`` values (``("s001", "posespace")``: one renderer, two schemes); ``help``: its part
    of the option's help (``"sg: ..."``); ``build(args, size)``: ``args`` the parsed ``prt play`` namespace
    (``args.renderer`` one of ``names``), ``size`` the image ``(H, W)`` -> the player, after checking the
    renderer's options (one-line :class:`~prt_torch.errors.PrtError`); ``add_arguments(parser)``: the options it
    adds to ``prt play`` (after ``--renderer``), or ``None``."""

    names: tuple[str, ...]
    help: str
    build: Callable[[argparse.Namespace, tuple[int, int]], Player]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None


def _build_onnx(args: argparse.Namespace, size: tuple[int, int]) -> Player:
    """The run's learned models through onnxruntime (``--graph compiled | fused | split | overlap | fused_peaks``;
    default: :func:`prt_torch.player.player.default_graph`)."""
    from prt_torch.player.player import Player

    if args.graph == "pipeline":
        raise PrtError("--graph pipeline plays a cloth run's --sequence (a skinned clip plays fused, split or "
                       "overlap)")
    return Player(args.run, env=args.env, brdf=args.brdf, graph=args.graph, threads=args.threads, window_size=size,
                  device=args.device, peaks=getattr(args, "peaks", None),
                  peak_kind=getattr(args, "peak_visibility", None))


#: the player's own renderer: the run's learned models (the default ``--renderer``)
ONNX = Renderer(names=("onnx",), help="onnx: the run's learned models", build=_build_onnx)

#: method package -> its ``--renderer`` hooks (:class:`Renderer` objects). The table's order is the order of the
#: ``--renderer`` choices and help (after ``onnx``).
RENDERERS: StageTable = {
    "vct": ("prt_torch.vct.play:SG",),
    "s001": ("prt_torch.s001.play:S001",),
    "transfer": ("prt_torch.transfer.play:TRANSFER",),
    "local": (),
    "shexp": (),
    "heightfield": (),
    "cloth": (),
}


def renderers() -> list[Renderer]:
    """``onnx`` first, then the method packages' renderers in :data:`RENDERERS` order (hook modules imported)."""
    return [ONNX, *hooks(RENDERERS)]


def renderer(name: str) -> Renderer:
    """The renderer answering to the ``--renderer`` value ``name`` (one-line error for an unknown one)."""
    found = [r for r in renderers() if name in r.names]
    if not found:
        raise PrtError(f"unknown renderer {name!r}: expected one of "
                       f"{', '.join(n for r in renderers() for n in r.names)}")
    return found[0]
