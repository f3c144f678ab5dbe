"""Which frames a run bakes: the character and its posed clips, from the config's ``character`` section.

Clip order in the dataset: ``train_clips``, then ``"random"`` (``random_poses`` random poses,
training; ``random_mode`` picks the sampler of :mod:`prt_torch.rig.random_pose`), then
``heldout_clips``. Splits: ``train`` = train clips + random; ``heldout`` = held-out clips. Named
clips are resampled at ``character.fps``; ``character.motions`` (motion files retargeted by
:mod:`prt_torch.rig.retarget`) become clips of the character first (:func:`add_motions`).

Each ``train_clips``/``heldout_clips`` entry (a clip name, or a frame range of a clip,
:class:`prt_torch.rig.config.ClipRange`) is one dataset clip with its own name; its ``frame_index``
is the frame's index in the whole (resampled) source clip. One clip may be split between training
and held-out sets; no frame may be used twice.

:func:`make_plan` is the ONE place that builds the random poses' source clips from the split: the
training entries' frames only (every mode: uniform without joint limits perturbs them, sparse uses
them as base poses, cpca clusters and resamples them), never a held-out clip or the held-out range of a split clip.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prt_torch.bake.deformable import source_of
from prt_torch.errors import PrtError
from prt_torch.rig.load import add_motions, check_disjoint, load_character, resolve_clips

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
        skin: ``(F, J, 4, 4)`` float64 skin matrices (``world @ inverse_bind``); a deformable plan's are the
            identity ``(F, 1, 4, 4)`` (its single root joint).
        positions: ``(F, V, 3)`` float32 vertex-cache positions of a deformable subject (cloth, issue 11: the
            bake traces these, never skinning; :mod:`prt_torch.bake.deformable`), None for a skinned character.
    """

    character: Character
    clip_names: list[str]
    splits: dict[str, list[str]]
    clip_id: np.ndarray
    frame_index: np.ndarray
    pose: np.ndarray
    skin: np.ndarray
    positions: np.ndarray | None = None

    @property
    def deformable(self) -> bool:
        return self.positions is not None

    @property
    def n_frames(self) -> int:
        return int(self.clip_id.shape[0])

    def fingerprint(self) -> str:
        """sha256 of the frame list: clip names, clip ids, frame indices, pose features, skin matrices (and a
        deformable plan's positions)."""
        h = hashlib.sha256()
        h.update("\n".join(self.clip_names).encode())
        for a in (self.clip_id.astype(np.int32), self.frame_index.astype(np.int32), self.pose.astype(np.float32),
                  self.skin.astype(np.float32), *(() if self.positions is None else (self.positions,))):
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()


def make_plan(cfg: RunConfig, character: Character | None = None) -> BakePlan:
    """Pose every frame the config asks for (validated: unknown clips, empty or overlapping ranges and empty
    sets are errors). The random poses' source clips are the training entries' frames, nothing else."""
    from prt_torch.rig.random_pose import random_poses

    source = source_of(cfg)
    if source is not None:  # a deformable subject: its source's plan (positions, no skinning)
        return source.plan(cfg)
    ch = cfg.character
    if character is None:
        character = load_character(cfg)
    elif any(m.name not in character.clips for m in ch.motions):  # a character passed in (not from
        character = add_motions(cfg, character)  # load_character) gets the config's motions as clips too
    train = resolve_clips(character, ch.train_clips, ch.fps, "train_clips")
    heldout = resolve_clips(character, ch.heldout_clips, ch.fps, "heldout_clips")
    check_disjoint(train, heldout)
    if ch.random_poses and (RANDOM_CLIP in character.clips or RANDOM_CLIP in [c.name for c in train + heldout]):
        raise PrtError(f"character has a clip named {RANDOM_CLIP!r}, which clashes with the random poses")
    if not train and not ch.random_poses:
        raise PrtError("nothing to train on: set character.train_clips or character.random_poses")
    names = [c.name for c in train]
    poses = [character.pose(c.clip) for c in train]
    frame_index = [c.frame_index for c in train]
    if ch.random_poses:
        names.append(RANDOM_CLIP)
        sources = [c.clip for c in train]  # the split's training frames: the only motion random poses start from
        rnd = random_poses(character, ch.random_poses, seed=ch.seed, perturb_deg=ch.random_perturb_deg, fps=ch.fps,
                           mode=ch.random_mode, base_clips=sources, base_clip_prob=ch.random_base_prob,
                           max_chains=ch.random_max_chains, segment=ch.random_segment,
                           near_base=ch.random_near_base, cpca_clusters=ch.random_cpca_clusters,
                           cpca_components=ch.random_cpca_components)
        poses.append(character.pose(rnd))
        frame_index.append(np.arange(rnd.num_frames))
    names += [c.name for c in heldout]
    poses += [character.pose(c.clip) for c in heldout]
    frame_index += [c.frame_index for c in heldout]
    clip_id = np.concatenate([np.full(p.num_frames, i, dtype=np.int32) for i, p in enumerate(poses)])
    frame_idx = np.concatenate(frame_index).astype(np.int32)
    pose = np.concatenate([p.features for p in poses]).astype(np.float32)
    skin = np.concatenate([p.skin for p in poses]).astype(np.float64)
    if not (np.isfinite(pose).all() and np.isfinite(skin).all()):
        raise PrtError("posed skeleton has NaN or Inf (pose features or skin matrices)")
    splits = {"train": [c.name for c in train] + ([RANDOM_CLIP] if ch.random_poses else []),
              "heldout": [c.name for c in heldout]}
    return BakePlan(character=character, clip_names=names, splits=splits, clip_id=clip_id,
                    frame_index=frame_idx, pose=pose, skin=skin)
