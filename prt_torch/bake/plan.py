"""Which frames a run bakes: the character and its posed clips, from the config's ``character`` section.

Clip order in the dataset: ``train_clips``, then ``"random"`` (``random_poses`` random poses,
training; ``random_mode`` picks the sampler of :mod:`prt_torch.rig.random_pose`, whose ``"sparse"``
base poses come from the bind pose and ``train_clips`` only, never the held-out clips), then
``heldout_clips``. Splits: ``train`` = train clips +
random; ``heldout`` = held-out clips. Named clips are resampled at ``character.fps``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prt_torch.errors import PrtError

if TYPE_CHECKING:
    from prt_torch.config import RunConfig
    from prt_torch.rig.character import Character

RANDOM_CLIP = "random"


@dataclass
class BakePlan:
    """All frames of a bake, in dataset order.

    Attributes:
        character: the skinned character.
        clip_names: names of the clips, indexed by ``clip_id``.
        splits: ``{"train": [...], "heldout": [...]}`` clip names.
        clip_id, frame_index: ``(F,)`` int32 clip of each frame and its index within the clip.
        pose: ``(F, A)`` float32 pose features.
        skin: ``(F, J, 4, 4)`` float64 skin matrices (``world @ inverse_bind``).
    """

    character: Character
    clip_names: list[str]
    splits: dict[str, list[str]]
    clip_id: np.ndarray
    frame_index: np.ndarray
    pose: np.ndarray
    skin: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.clip_id.shape[0])

    def fingerprint(self) -> str:
        """sha256 of the frame list: clip names, clip ids, frame indices and pose features."""
        h = hashlib.sha256()
        h.update("\n".join(self.clip_names).encode())
        for a in (self.clip_id.astype(np.int32), self.frame_index.astype(np.int32), self.pose.astype(np.float32),
                  self.skin.astype(np.float32)):
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()


def load_character(cfg: RunConfig) -> Character:
    """The character of a run: the built-in humanoid or a glTF file (``character.source``)."""
    ch = cfg.character
    if ch.source == "builtin":
        from prt_torch.rig.builtin import make_character

        return make_character(ch.density, fps=ch.fps)
    path = cfg.resolve(ch.source)
    if path.suffix.lower() not in (".glb", ".gltf"):
        raise PrtError(f"unknown character source {ch.source!r}: expected 'builtin' or a .glb/.gltf file")
    if not path.is_file():
        raise PrtError(f"character file not found: {path}")
    from prt_torch.rig.gltf import load_gltf

    return load_gltf(path, fps=ch.fps, height=ch.height)


def make_plan(cfg: RunConfig, character: Character | None = None) -> BakePlan:
    """Pose every frame the config asks for (validated: unknown clips and empty sets are errors)."""
    from prt_torch.rig.random_pose import random_poses

    character = load_character(cfg) if character is None else character
    ch = cfg.character
    train = list(ch.train_clips)
    heldout = list(ch.heldout_clips)
    for name in train + heldout:
        if name not in character.clips:
            raise PrtError(f"unknown clip {name!r} for character {character.name!r}; available: "
                           f"{sorted(character.clips)}")
    dup = sorted({n for n in train + heldout if (train + heldout).count(n) > 1})
    if dup:
        raise PrtError(f"clip listed twice in train_clips/heldout_clips: {dup[0]!r}")
    if RANDOM_CLIP in character.clips and ch.random_poses:
        raise PrtError(f"character has a clip named {RANDOM_CLIP!r}, which clashes with the random poses")
    if not train and not ch.random_poses:
        raise PrtError("nothing to train on: set character.train_clips or character.random_poses")
    names, poses = [], []
    for name in train:
        names.append(name)
        poses.append(character.pose(name, fps=ch.fps))
    if ch.random_poses:
        names.append(RANDOM_CLIP)
        rnd = random_poses(character, ch.random_poses, seed=ch.seed, fps=ch.fps, mode=ch.random_mode,
                           base_clips=train, base_clip_prob=ch.random_base_prob, max_chains=ch.random_max_chains,
                           segment=ch.random_segment, near_base=ch.random_near_base)
        poses.append(character.pose(rnd))
    for name in heldout:
        names.append(name)
        poses.append(character.pose(name, fps=ch.fps))
    clip_id = np.concatenate([np.full(p.num_frames, i, dtype=np.int32) for i, p in enumerate(poses)])
    frame_index = np.concatenate([np.arange(p.num_frames, dtype=np.int32) for p in poses])
    pose = np.concatenate([p.features for p in poses]).astype(np.float32)
    skin = np.concatenate([p.skin for p in poses]).astype(np.float64)
    if not (np.isfinite(pose).all() and np.isfinite(skin).all()):
        raise PrtError("posed skeleton has NaN or Inf (pose features or skin matrices)")
    splits = {"train": train + ([RANDOM_CLIP] if ch.random_poses else []), "heldout": heldout}
    return BakePlan(character=character, clip_names=names, splits=splits, clip_id=clip_id,
                    frame_index=frame_index, pose=pose, skin=skin)
