"""A run's character and its clip entries, from the config's ``character`` section: :func:`load_character` (the
built-in humanoid or a glTF file, plus ``character.motions`` retargeted as clips, :func:`add_motions`),
:func:`resolve_clips` (``train_clips``/``heldout_clips`` entries to frames of the character's clips),
:func:`check_disjoint` (no frame used twice) and :func:`clip_by_name` (a clip name as a run uses it - a split's
dataset clip or a clip of the character - to frames of the character's clips). The bake plan
(:mod:`prt_torch.bake.plan`) and the cape's subject (:mod:`prt_torch.cloth.subject`) use the first two;
``prt compare`` and ``prt play`` the last (through :meth:`prt_torch.bake.store.BakedDataset.clip_by_name`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prt_torch.errors import PrtError, warn
from prt_torch.rig.clip import Clip
from prt_torch.rig.config import ClipRange, as_clip_range

if TYPE_CHECKING:
    from prt_torch.config import RunConfig
    from prt_torch.rig.character import Character
    from prt_torch.rig.config import CharacterConfig


def load_character(cfg: RunConfig) -> Character:
    """The character of a run: the built-in humanoid or a glTF file (``character.source``); for a cloth run the
    cape's body (its subject, body + cloth, is :attr:`prt_torch.cloth.subject.ClothSubject.character`). A key set
    that has no effect on this character (:meth:`~prt_torch.rig.config.CharacterConfig.ineffective_keys`) is one
    warning line."""
    ch = cfg.character
    if ch.source == "builtin":
        from prt_torch.rig.builtin import make_character

        character = make_character(ch.density, fps=ch.fps)
    else:
        path = cfg.resolve(ch.source)
        if path.suffix.lower() not in (".glb", ".gltf"):
            raise PrtError(f"unknown character source {ch.source!r}: expected 'builtin' or a .glb/.gltf file")
        if not path.is_file():
            raise PrtError(f"character file not found: {path}")
        from prt_torch.rig.gltf import load_gltf

        character = load_gltf(path, fps=ch.fps, height=ch.height)
    for message in ch.ineffective_keys(ch.source == "builtin", character.joint_limits is not None):
        warn(message)
    if ch.subdivide:  # low-poly characters: bake and shade a subdivided copy, same skeleton and skin
        from prt_torch.rig.lowpoly import subdivide_character

        character = subdivide_character(character, ch.subdivide)
    return add_motions(cfg, character)


def add_motions(cfg: RunConfig, character: Character) -> Character:
    """Retarget ``character.motions`` (files resolved against the config file) onto ``character`` as clips named
    by each entry (``fps`` default ``character.fps``, then the ``frames`` slice). A missing or malformed file, a
    non-humanoid skeleton, an empty slice or a name clash is a one-line :class:`PrtError` naming the entry."""
    from prt_torch.rig.retarget import retarget_file

    for i, m in enumerate(cfg.character.motions):
        key = f"character.motions[{i}] ({m.name!r})"
        if m.name in character.clips:
            raise PrtError(f"{key}: the character already has a clip named {m.name!r}")
        path = cfg.resolve(m.file)
        if not path.is_file():
            raise PrtError(f"{key}: motion file not found: {path}")
        try:
            clip, report = retarget_file(path, character, fps=m.fps or cfg.character.fps, joint_map=m.joint_map,
                                         name=m.name, skip_first=m.skip_first, clip=m.clip)
        except PrtError as e:
            raise PrtError(f"{key}: {e}") from None
        for w in report.warnings:  # what the retargeting detected and fixed up (units, reference frame, frame rate)
            warn(f"{key}: {w.removeprefix('warning: ')}")
        local = clip.local[m.frame_slice()]
        if local.shape[0] == 0:
            raise PrtError(f"{key}: frames {m.frames!r} select no frame of {clip.num_frames}")
        character.clips[m.name] = Clip(m.name, clip.fps, local)
    return character


@dataclass
class PlanClip:
    """One ``train_clips``/``heldout_clips`` entry resolved against the character.

    Attributes:
        name: the dataset clip name.
        source: the character clip it is cut from.
        frame_index: ``(F',)`` int64 indices into the source clip resampled at ``character.fps``.
        clip: those frames as a :class:`Clip` (``local (F', J, 4, 4)``), named ``name``.
    """

    name: str
    source: str
    frame_index: np.ndarray
    clip: Clip


def resolve_clips(character: Character, entries: Sequence[str | ClipRange], fps: float, key: str) -> list[PlanClip]:
    """Resolve config entries (clip names or :class:`ClipRange`) to frames of the character's clips at ``fps``.

    Unknown clips and ranges that select no frame are one-line :class:`PrtError` naming ``key``.
    """
    out = []
    for i, entry in enumerate(entries):
        r = as_clip_range(entry)
        if r.clip not in character.clips:
            raise PrtError(f"unknown clip {r.clip!r} in {key}[{i}] for character {character.name!r}; available: "
                           f"{sorted(character.clips)}")
        full = character.clips[r.clip]
        if fps != full.fps:  # as Character.pose(name, fps=...)
            full = full.resample(fps)
        idx = r.frame_indices(full.num_frames, fps)
        if idx.size == 0:
            raise PrtError(f"{key}[{i}]: {r.dataset_name!r} selects no frame of clip {r.clip!r} "
                           f"({full.num_frames} frames at {fps:g} fps)")
        out.append(PlanClip(r.dataset_name, r.clip, idx, Clip(r.dataset_name, full.fps, full.local[idx])))
    return out


def clip_by_name(character: Character, name: str, cfg: CharacterConfig | None = None,
                 fps: float | None = None) -> PlanClip:
    """THE rule from a clip name, as a run uses it, to frames of the character's clips.

    A ``train_clips``/``heldout_clips`` entry of ``cfg`` named ``name`` (its dataset name) that cuts a frame range of
    a clip or renames one (e.g. ``{clip: animation_0, frames: "36:", name: walk_tail}``: frames 36.. of
    ``animation_0``) resolves as the bake resolved it (:func:`resolve_clips` at ``cfg.fps``); any other name is a
    clip of the character, whole, resampled at ``fps`` when given (its own rate otherwise). The result's
    ``frame_index (F',)`` indexes the source clip at that rate, as the dataset's ``frame_index`` does. A name that
    is neither is one :class:`PrtError` naming both lists.
    """
    if cfg is not None:
        for key, entries in (("train_clips", cfg.train_clips), ("heldout_clips", cfg.heldout_clips)):
            for i, entry in enumerate(entries):
                r = as_clip_range(entry)
                if r.dataset_name == name and r != ClipRange(clip=name):
                    return resolve_clips(character, [r], cfg.fps, f"{key}[{i}]")[0]
    if name not in character.clips:
        split = [] if cfg is None else [as_clip_range(e).dataset_name for e in (*cfg.train_clips, *cfg.heldout_clips)]
        raise PrtError(f"unknown clip {name!r} for character {character.name!r}; available: {sorted(character.clips)}"
                       + (f"; the run's split clips: {split}" if split else ""))
    clip = character.clips[name]
    if fps is not None and fps != clip.fps:  # as Character.pose(name, fps=...)
        clip = clip.resample(fps)
    return PlanClip(name, name, np.arange(clip.num_frames, dtype=np.int64), clip)


def check_disjoint(train: list[PlanClip], heldout: list[PlanClip]) -> None:
    """No dataset clip name twice, and no frame of a source clip in two entries (train vs held-out above all)."""
    entries = [("train_clips", c) for c in train] + [("heldout_clips", c) for c in heldout]
    for i, (key, c) in enumerate(entries):
        for other_key, o in entries[:i]:
            if o.name == c.name:
                raise PrtError(f"clip listed twice in train_clips/heldout_clips: {c.name!r}")
            if o.source == c.source and np.intersect1d(o.frame_index, c.frame_index).size:
                raise PrtError(f"{key} entry {c.name!r} and {other_key} entry {o.name!r} share frames of clip "
                               f"{c.source!r}")
