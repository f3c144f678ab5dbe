"""The run-time player (onnxruntime + numpy + pyvista; never torch): :class:`Player`."""

from prt_torch.player.player import Player, PlayResult
from prt_torch.player.posing import PoseBatch, Poser

__all__ = ["PlayResult", "PoseBatch", "Player", "Poser"]
