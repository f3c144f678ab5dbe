"""Deformable subjects in the bake: the ONE rule a deformable dataset follows, and the table of their sources.

A deformable run's frames are not skinned: the positions of every frame come from a source the run config
selects (a method package's :class:`DeformableSource`, listed in :data:`SUBJECTS`; cloth: the vertex cache its
simulation writes), the subject is a single-root-joint character, and

- clusters: :func:`clusters` (k-means of the rest vertices, :func:`prt_torch.deform.clusters.spatial_clusters`,
  ``bake.max_clusters`` clusters, ``bake.seed``), stored as the dataset's ``cluster``;
- vertex frames: the :class:`prt_torch.deform.frames.FrameOperator` of the rest mesh and those labels
  (:func:`frame_operator`); the normals are its ``n`` rows (:func:`posed_frames`).

The bake's workers, ``prt compare``, the fits and the export rebuild the frames from ``character.npz`` and the
dataset's ``cluster`` with these functions; :func:`is_deformable` is the one test of "is this run deformable".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.plugins import StageTable, hooks

if TYPE_CHECKING:
    from prt_torch.bake.plan import BakePlan
    from prt_torch.config import RunConfig
    from prt_torch.deform.frames import FrameOperator
    from prt_torch.rig.character import Character


@dataclass(frozen=True)
class DeformableSource:
    """A deformable subject's source of frames: a method package's bake hook (:data:`SUBJECTS`).

    Attributes:
        section: the run config section that selects this source (``cfg.<section>`` set, e.g. ``"cloth"``); a
            store records it in ``attrs["config"]``.
        prepare: ``prepare(cfg, progress)``: make every frame the run bakes available (e.g. simulate what the
            cache lacks), before the plan; :func:`prt_torch.bake.runner.run_bake` calls it before anything else.
        plan: ``plan(cfg)``: the run's :class:`~prt_torch.bake.plan.BakePlan` with ``positions (F, V, 3)``
            float32 set (the frames traced as they are) and the identity ``skin (F, 1, 4, 4)``.
        read: ``read(cfg, name)``: one named sequence as ``prt compare --clip`` poses it, an object with
            ``positions (T, V, 3)`` float32 and ``features (T, A)`` float32 (the dataset's ``pose`` column); a
            missing sequence or cache is a one-line PrtError.
    """

    section: str
    prepare: Callable[[RunConfig, bool], object]
    plan: Callable[[RunConfig], BakePlan]
    read: Callable[[RunConfig, str], Any]


#: the deformable subject sources: method package -> its :class:`DeformableSource` (``()``: none)
SUBJECTS: StageTable = {
    "s001": (),
    "transfer": (),
    "local": (),
    "shexp": (),
    "vct": (),
    "heightfield": (),
    "cloth": ("prt_torch.cloth.bake:SOURCE",),
}


def sources() -> list[DeformableSource]:
    """Every :class:`DeformableSource` of :data:`SUBJECTS`, loaded."""
    return hooks(SUBJECTS)


def source_of(cfg: RunConfig) -> DeformableSource | None:
    """The source the run config selects (its section is set), None for a skinned character."""
    for src in sources():
        if getattr(cfg, src.section, None) is not None:
            return src
    return None


def is_deformable(attrs_or_cfg: Any) -> bool:
    """Whether a run config (a :data:`SUBJECTS` source's section set) or a dataset's attrs (``deformable: true``,
    or a recorded config with such a section) is deformable: the one rule (export, compare, fit and the bake ask
    it)."""
    if isinstance(attrs_or_cfg, dict):
        from prt_torch.bake.store import recorded_config

        recorded = recorded_config(attrs_or_cfg)
        return bool(attrs_or_cfg.get("deformable", False)) or any(bool(recorded.get(s.section)) for s in sources())
    return source_of(attrs_or_cfg) is not None


def clusters(character: Character, n_clusters: int, seed: int) -> np.ndarray:
    """``(V,)`` int32 cluster of each vertex: k-means of the rest vertices (at most one cluster per vertex)."""
    from prt_torch.deform.clusters import spatial_clusters

    k = max(1, min(int(n_clusters), character.num_vertices))
    return np.asarray(spatial_clusters(character.rest_vertices, k, seed), dtype=np.int32)


def frame_operator(character: Character, labels: np.ndarray) -> FrameOperator:
    """The :class:`~prt_torch.deform.frames.FrameOperator` of a deformable subject (rest mesh + cluster labels):
    rebuilt identically by the bake's workers, ``prt compare`` and the export from ``character.npz`` and the
    dataset's ``cluster``."""
    from prt_torch.deform.frames import FrameOperator

    return FrameOperator.from_rest(np.asarray(character.rest_vertices), np.asarray(character.faces),
                                   np.asarray(labels))


def posed_frames(op: FrameOperator, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(normals (F, V, 3), frames (F, V, 3, 3))`` float32 of ``positions (F, V, 3)``: the FrameOperator's frames
    (rows t, b, n); the normals are their ``n`` rows (the smooth posed normals)."""
    frames = np.asarray(op.frames(np.asarray(positions)), dtype=np.float32)
    if frames.ndim == 3:
        frames = frames[None]
    return np.ascontiguousarray(frames[:, :, 2, :]), frames
