"""Character section of a run config (owned by :mod:`prt_torch.rig`)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class CharacterConfig(BaseModel):
    """Which character to load and which clips make the training and held-out sets.

    ``source`` is ``"builtin"`` (the procedural humanoid) or a path to a ``.glb``/``.gltf`` file
    (relative paths are resolved against the config file's directory).
    """

    model_config = ConfigDict(extra="forbid")

    source: str = "builtin"
    density: float = Field(default=1.0, gt=0)  # built-in character only: vertex density factor
    height: float | None = Field(default=None, gt=0)  # glTF only: rescale to this height (load_gltf(height=...))
    fps: float = Field(default=30.0, gt=0)  # sampling rate for clips
    train_clips: list[str] = Field(default_factory=list)
    heldout_clips: list[str] = Field(default_factory=list)
    random_poses: int = Field(default=0, ge=0)  # random poses within joint limits added to training
    seed: int = 0
