"""Character section of a run config (owned by :mod:`prt_torch.rig`)."""

from __future__ import annotations

from typing import Literal

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
    # how they are sampled (prt_torch.rig.random_pose): "uniform" moves every joint; "sparse" moves
    # 1..random_max_chains joint chains of the bind pose or (probability random_base_prob) of a random
    # train_clips frame, key poses joined by random_segment interpolated frames (1 = independent poses)
    random_mode: Literal["uniform", "sparse"] = "uniform"
    random_max_chains: int = Field(default=3, ge=1)
    random_base_prob: float = Field(default=0.5, ge=0.0, le=1.0)
    random_segment: int = Field(default=1, ge=1)
    random_near_base: float = Field(default=0.0, ge=0.0, le=1.0)  # sparse: P(moved joint lands near its base)
    seed: int = 0
