"""Character section of a run config (owned by :mod:`prt_torch.rig`)."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationInfo, field_validator, model_validator

from prt_torch import limits as L

_INT = r"\s*(-?\d+)?\s*"
_NUM = r"\s*([^:\s]+)?\s*"


def _parse_frames(text: str) -> tuple[int | None, int | None]:
    """``"a:b"`` (either end optional, python slice semantics, negative = from the end) -> ``(a, b)``."""
    m = re.fullmatch(f"{_INT}:{_INT}", text)
    if m is None:
        raise ValueError(f"bad frame range {text!r}: expected 'start:stop' (integers, either optional)")
    out = tuple(None if g is None else int(g) for g in m.groups())  # text is at most 64 characters
    if any(g is not None and abs(g) > L.MAX_FRAME_INDEX for g in out):
        raise ValueError(f"bad frame range {text!r}: frame indices must be within +-{L.MAX_FRAME_INDEX}")
    return out  # type: ignore[return-value]


def _parse_times(text: str) -> tuple[float | None, float | None]:
    """``"t0:t1"`` seconds (either end optional, finite, >= 0) -> ``(t0, t1)``."""
    m = re.fullmatch(f"{_NUM}:{_NUM}", text)
    out: list[float | None] = []
    for g in m.groups() if m is not None else ("?",):
        try:
            t = None if g is None else float(g)
        except ValueError:
            t = -1.0
        if t is not None and not (math.isfinite(t) and 0 <= t <= L.MAX_CLIP_SECONDS):
            raise ValueError(f"bad time range {text!r}: expected 't0:t1' seconds (numbers in "
                             f"[0, {L.MAX_CLIP_SECONDS:g}], either optional)")
        out.append(t)
    return out[0], out[1]


def _checked_frames(v: str | None) -> str | None:
    """A ``frames: "a:b"`` slice string that parses and selects a non-empty range (when both ends have one sign)."""
    if v is not None:
        start, stop = _parse_frames(v)
        if start is not None and stop is not None and (start >= 0) == (stop >= 0) and stop <= start:
            raise ValueError(f"empty frame range {v!r}")
    return v


def _checked_path(v: str) -> str:
    """A path string of a config (no NUL character, which no file system accepts)."""
    if "\x00" in v:
        raise ValueError("a path must not contain a NUL character")
    return v


class ClipRange(BaseModel):
    """A frame range of one of the character's clips, used as its own dataset clip.

    ``{clip: Walk, frames: "0:28"}``: a python slice ``start:stop`` of the clip's frame indices at
    ``character.fps`` (after resampling; either end optional, negative counts from the end; no step).
    ``{clip: Walk, times: "0.5:1.2"}``: the frames ``f`` with ``t0 <= f / fps < t1`` (seconds, either end
    optional). Neither: the whole clip. ``name``: the dataset clip name (default ``Walk[0:28]``,
    ``Walk[0.5s:1.2s]``, or ``Walk`` for the whole clip).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    clip: str = Field(min_length=1, max_length=L.MAX_STRING_LENGTH)
    frames: str | None = Field(default=None, max_length=64)
    times: str | None = Field(default=None, max_length=64)
    name: str | None = Field(default=None, min_length=1, max_length=L.MAX_STRING_LENGTH)

    @field_validator("frames")
    @classmethod
    def _check_frames(cls, v: str | None) -> str | None:
        return _checked_frames(v)

    @field_validator("times")
    @classmethod
    def _check_times(cls, v: str | None) -> str | None:
        if v is not None:
            t0, t1 = _parse_times(v)
            if t0 is not None and t1 is not None and t1 <= t0:
                raise ValueError(f"empty time range {v!r}")
        return v

    @model_validator(mode="after")
    def _one_range(self) -> ClipRange:
        if self.frames is not None and self.times is not None:
            raise ValueError(f"clip {self.clip!r}: give either 'frames' or 'times', not both")
        return self

    @property
    def dataset_name(self) -> str:
        """The name of this entry's clip in the dataset."""
        if self.name is not None:
            return self.name
        if self.frames is not None:
            start, stop = _parse_frames(self.frames)
            return f"{self.clip}[{'' if start is None else start}:{'' if stop is None else stop}]"
        if self.times is not None:
            t0, t1 = _parse_times(self.times)
            return f"{self.clip}[{'' if t0 is None else f'{t0:g}s'}:{'' if t1 is None else f'{t1:g}s'}]"
        return self.clip

    def frame_slice(self, fps: float) -> slice:
        """The frame indices of this entry (at ``fps``) as a python slice of the clip's frames."""
        if self.times is not None:
            t0, t1 = _parse_times(self.times)
            return slice(None if t0 is None else math.ceil(t0 * fps - 1e-9),
                         None if t1 is None else math.ceil(t1 * fps - 1e-9))
        if self.frames is not None:
            return slice(*_parse_frames(self.frames))
        return slice(None)

    def frame_indices(self, n_frames: int, fps: float) -> np.ndarray:
        """``(F',)`` int64 indices into a clip of ``n_frames`` frames at ``fps`` (may be empty)."""
        return np.arange(n_frames, dtype=np.int64)[self.frame_slice(fps)]


def _entry_tag(v: Any) -> str:
    return "range" if isinstance(v, dict | ClipRange) else "name"


#: a ``train_clips``/``heldout_clips`` entry: a clip name (the whole clip) or a :class:`ClipRange`
ClipEntry = Annotated[Annotated[str, Tag("name")] | Annotated[ClipRange, Tag("range")], Discriminator(_entry_tag)]


def as_clip_range(entry: str | ClipRange) -> ClipRange:
    """A plain clip name as the :class:`ClipRange` of the whole clip; a :class:`ClipRange` unchanged."""
    return ClipRange(clip=entry) if isinstance(entry, str) else entry


def _static_bounds(entry: ClipRange, fps: float) -> tuple[int, float] | None:
    """``[start, stop)`` frame bounds known without the clip's length, or ``None`` (negative indices)."""
    s = entry.frame_slice(fps)
    start = 0 if s.start is None else s.start
    stop = math.inf if s.stop is None else s.stop
    return None if start < 0 or stop < 0 else (start, stop)


def _check_entries(entries: list[str | ClipRange], others: list[str | ClipRange], key: str, other_key: str,
                   fps: float | None) -> None:
    """Empty ranges, duplicate dataset names and overlapping ranges of one clip (those known statically)."""
    fps = 30.0 if fps is None else fps
    ranges = [as_clip_range(e) for e in entries]
    prior = [as_clip_range(e) for e in others]
    for i, r in enumerate(ranges):
        b = _static_bounds(r, fps)
        if b is not None and b[1] <= b[0]:
            raise ValueError(f"{key}[{i}]: {r.dataset_name!r} selects no frame at {fps:g} fps")
        for where, other in [(key, o) for o in ranges[:i]] + [(other_key, o) for o in prior]:
            if other.dataset_name == r.dataset_name:
                raise ValueError(f"{key}[{i}]: clip name {r.dataset_name!r} is already used in {where}")
            if other.clip != r.clip:
                continue
            c = _static_bounds(other, fps)
            if b is not None and c is not None and b[0] < c[1] and c[0] < b[1]:
                raise ValueError(f"{key}[{i}]: {r.dataset_name!r} overlaps {other.dataset_name!r} in {where} "
                                 f"(frames of one clip must not be used twice)")


class MotionConfig(BaseModel):
    """A motion file retargeted onto the character (:mod:`prt_torch.rig.retarget`) as one of its clips.

    ``{file: ../shared/data/motion/94_01.bvh, name: dance, fps: 30, frames: "1:1800", joint_map: {...}}``:
    ``file`` a ``.bvh`` or humanoid ``.glb``/``.gltf`` (relative to the config file, like ``source``); ``name``
    the clip name (usable in ``train_clips``/``heldout_clips``); ``fps`` the resampling rate (default
    ``character.fps``); ``frames`` a python slice of the resampled frames (after a converter's reference-pose
    frame 1 is skipped: ``skip_first``, default detected by the retargeting); ``joint_map`` ``{source joint:
    target joint}`` overrides of the default map (``null`` unmaps a source joint); ``clip`` the glTF animation
    (default: the first).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    file: str = Field(min_length=1, max_length=L.MAX_STRING_LENGTH)
    name: str = Field(min_length=1, max_length=L.MAX_STRING_LENGTH)
    fps: float | None = Field(default=None, gt=0, le=L.MAX_FPS)
    frames: str | None = Field(default=None, max_length=64)
    joint_map: dict[str, str | None] = Field(default_factory=dict, max_length=L.MAX_LIST_LENGTH)
    clip: str | None = Field(default=None, min_length=1, max_length=L.MAX_STRING_LENGTH)
    skip_first: bool | None = None

    @field_validator("file")
    @classmethod
    def _check_file(cls, v: str) -> str:
        return _checked_path(v)

    @field_validator("frames")
    @classmethod
    def _check_frames(cls, v: str | None) -> str | None:
        return _checked_frames(v)

    def frame_slice(self) -> slice:
        """The selected frames of the retargeted (resampled) motion."""
        return slice(*_parse_frames(self.frames)) if self.frames is not None else slice(None)


class CharacterConfig(BaseModel):
    """Which character to load and which clips make the training and held-out sets.

    ``source`` is ``"builtin"`` (the procedural humanoid) or a path to a ``.glb``/``.gltf`` file
    (relative paths are resolved against the config file's directory).

    ``train_clips`` / ``heldout_clips`` entries are clip names (the whole clip) or frame ranges of a
    clip, ``{clip: Walk, frames: "0:28"}`` / ``{clip: Walk, times: "0.5:"}`` (optional ``name:``; see
    :class:`ClipRange`), each its own dataset clip; one clip may be split between the two sets, but
    no frame may be used twice (overlaps are errors). Random training poses are built from the
    training entries' frames only (:func:`prt_torch.bake.plan.make_plan`).

    ``random_perturb_deg`` is the perturbation range of random poses of characters WITHOUT joint
    limits (every glTF/BVH character): each non-root joint of a training frame is rotated by up to
    this many degrees about a random axis (``random_mode: uniform``), or the joints of the moved
    chains are (``sparse``). Characters with joint limits (the built-in humanoid) ignore it. Likewise ``density``
    applies to the built-in humanoid only and ``height`` to a glTF file only; a key set where it has no effect is
    one warning line when the character is loaded (:meth:`ineffective_keys`).

    ``random_mode: cpca`` resamples the training frames' pose space (seed 001 sec. 2): k-means of their
    pose features into ``random_cpca_clusters`` clusters (1..64), a ``random_cpca_components``-component
    PCA per cluster (1..54, at most the feature dimension ``6 x`` non-root joints), stratified samples
    of each cluster's observed coefficient ranges (``random_poses`` spread evenly over the clusters),
    projected back to rotations and clamped to the joint limits when there are any; root and joint
    translations come from the cluster's nearest training frame. It needs ``train_clips``.

    Every number is finite and bounded (:mod:`prt_torch.limits`): ``density`` in
    ``[MIN_DENSITY, MAX_DENSITY]``, ``fps`` in ``(0, MAX_FPS]``, ``random_poses <= MAX_RANDOM_POSES``,
    ``seed`` in ``0..MAX_SEED``.

    ``subdivide: N`` (0..4, default 0) bakes, trains and shades a copy of the character's mesh split ``N`` times by
    edge midpoints (``4^N`` faces; skin weights, normals and UVs interpolated:
    :func:`prt_torch.rig.lowpoly.subdivide_character`), for low-poly characters whose per-vertex shadows would be
    blotches (``prt info`` says when: :func:`prt_torch.rig.lowpoly.low_poly_advice`).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    source: str = Field(default="builtin", min_length=1, max_length=L.MAX_STRING_LENGTH)
    # built-in character only: vertex density factor
    density: float = Field(default=1.0, ge=L.MIN_DENSITY, le=L.MAX_DENSITY)
    # glTF only: rescale to this height (load_gltf(height=...))
    height: float | None = Field(default=None, gt=0, le=L.MAX_HEIGHT)
    fps: float = Field(default=30.0, gt=0, le=L.MAX_FPS)  # sampling rate for clips
    # midpoint subdivision levels of the shading mesh (prt_torch.rig.lowpoly: low-poly characters), 4^N faces
    subdivide: int = Field(default=0, ge=0, le=4)
    train_clips: list[ClipEntry] = Field(default_factory=list, max_length=L.MAX_LIST_LENGTH)
    heldout_clips: list[ClipEntry] = Field(default_factory=list, max_length=L.MAX_LIST_LENGTH)
    # random poses within joint limits added to training
    random_poses: int = Field(default=0, ge=0, le=L.MAX_RANDOM_POSES)
    # how they are sampled (prt_torch.rig.random_pose): "uniform" moves every joint; "sparse" moves
    # 1..random_max_chains joint chains of the bind pose or (probability random_base_prob) of a random
    # train_clips frame, key poses joined by random_segment interpolated frames (1 = independent poses)
    random_mode: Literal["uniform", "sparse", "cpca"] = "uniform"
    random_cpca_clusters: int = Field(default=8, ge=1, le=64)  # cpca: k-means clusters of the training poses
    random_cpca_components: int = Field(default=8, ge=1, le=54)  # cpca: principal components per cluster
    random_max_chains: int = Field(default=3, ge=1, le=64)
    random_base_prob: float = Field(default=0.5, ge=0.0, le=1.0)
    random_segment: int = Field(default=1, ge=1, le=L.MAX_FRAMES)
    random_near_base: float = Field(default=0.0, ge=0.0, le=1.0)  # sparse: P(moved joint lands near its base)
    random_perturb_deg: float = Field(default=20.0, ge=0.0, le=180.0)  # no joint limits: perturbation range
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)
    # motion files retargeted onto the character as clips (MotionConfig; prt_torch.rig.retarget)
    motions: list[MotionConfig] = Field(default_factory=list, max_length=L.MAX_LIST_LENGTH)

    def ineffective_keys(self, builtin: bool, joint_limits: bool) -> list[str]:
        """One line for each key set in this section that has no effect on the character it loads (``builtin``:
        the built-in humanoid, else a glTF file; ``joint_limits``: the character has joint limits), saying why:
        ``density`` (the built-in humanoid only), ``height`` (glTF only), ``random_perturb_deg`` (characters
        without joint limits only)."""
        out = []
        if not builtin and "density" in self.model_fields_set:
            out.append("character.density has no effect on a glTF character (it sets the built-in humanoid's "
                       "vertex density); ignored")
        if builtin and self.height is not None:
            out.append("character.height has no effect on the built-in character (it rescales a glTF file); ignored")
        if joint_limits and "random_perturb_deg" in self.model_fields_set:
            out.append("character.random_perturb_deg has no effect on a character with joint limits (the built-in "
                       "humanoid's random poses are drawn within its limits); ignored")
        return out

    @field_validator("motions")
    @classmethod
    def _check_motions(cls, v: list[MotionConfig]) -> list[MotionConfig]:
        names = [m.name for m in v]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"motions[{i}]: name {n!r} is used twice")
        return v

    @field_validator("source")
    @classmethod
    def _check_source(cls, v: str) -> str:
        return _checked_path(v)

    @field_validator("train_clips")
    @classmethod
    def _check_train(cls, v: list[str | ClipRange], info: ValidationInfo) -> list[str | ClipRange]:
        _check_entries(v, [], "train_clips", "train_clips", info.data.get("fps"))
        return v

    @field_validator("heldout_clips")
    @classmethod
    def _check_heldout(cls, v: list[str | ClipRange], info: ValidationInfo) -> list[str | ClipRange]:
        _check_entries(v, list(info.data.get("train_clips", [])), "heldout_clips", "train_clips",
                       info.data.get("fps"))
        return v
