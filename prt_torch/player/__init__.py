"""The run-time player (onnxruntime + numpy + pyvista; never torch): :class:`Player`."""

from prt_torch.player.player import FrameState, Player, PlayResult

__all__ = ["FrameState", "PlayResult", "Player"]
