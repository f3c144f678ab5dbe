"""The cloth subject's source of frames in the bake (issue 11): vertex-cache positions -> the run's bake plan.

A cloth run's frames are not skinned: the positions of every frame come from the run's vertex cache
(``simulation.zarr``, :class:`prt_torch.cloth.cache.VertexCache`, written by
:func:`prt_torch.cloth.simulate.simulate`), the subject is the single-root-joint character
:attr:`prt_torch.cloth.subject.ClothSubject.character` (body + cloth for the cape, the cloth alone for the flag),
its pose features are :func:`prt_torch.cloth.inputs.cloth_features` of each frame (signed dihedral angles of the
cloth's interior edges, + the body's pose features when ``cloth.append_pose``), the dataset's ``pose`` column.
Clusters and vertex frames follow the core deformable rule (:mod:`prt_torch.bake.deformable`).

:data:`SOURCE` is the cloth's entry of :data:`prt_torch.bake.deformable.SUBJECTS`: :func:`ensure_simulated`
before the plan, :func:`make_deformable_plan` the plan. :func:`sequence_frames` is used by the plan and by
``prt compare --clip`` alike: nothing else computes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.bake.deformable import DeformableSource
from prt_torch.errors import DamagedArtifact, PrtError, StaleArtifact
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    from prt_torch.bake.plan import BakePlan
    from prt_torch.config import RunConfig


def simulation_path(cfg: RunConfig) -> Path:
    """The run's vertex cache, ``<out_dir>/simulation.zarr`` (:attr:`prt_torch.rundir.RunDir.simulation`)."""
    from prt_torch.rundir import RunDir

    return Path(RunDir(cfg.out_dir.resolve()).simulation)


@dataclass
class CachedSequence:
    """One cached sequence of a deformable subject: ``positions (T, V, 3)`` float32 and ``features (T, A)``
    float32 (the dataset's ``pose`` column)."""

    name: str
    positions: np.ndarray
    features: np.ndarray


def check_positions(positions: np.ndarray, n_vertices: int, what: str) -> np.ndarray:
    """``positions`` as float32 ``(T, n_vertices, 3)`` with T >= 1 and finite values, else a one-line PrtError."""
    p = np.asarray(positions)
    check_shape(p, "T V 3", name=f"{what}: positions")
    if p.shape[0] < 1:
        raise PrtError(f"{what}: positions of shape {p.shape}, expected (frames, {n_vertices}, 3)")
    if p.shape[1] != n_vertices:
        raise PrtError(f"{what}: {p.shape[1]} vertices per frame, the subject has {n_vertices} (a cache of "
                       f"another subject: delete the run's vertex cache and simulate again)")
    bad = ~np.isfinite(p).all(axis=(1, 2))
    if bad.any():
        raise PrtError(f"{what}: NaN or Inf positions in {int(bad.sum())} frame(s) (first: frame "
                       f"{int(np.argmax(bad))}); the simulation blew up or the cache is damaged")
    return p.astype(np.float32, copy=False)


def load_subject(cfg: RunConfig) -> Any:
    """The run's :class:`~prt_torch.cloth.subject.ClothSubject` (deterministic from the config)."""
    from prt_torch.cloth.subject import ClothSubject

    return ClothSubject.load(cfg)


def open_cache(cfg: RunConfig, path: Path | None = None) -> Any:
    """The run's :class:`~prt_torch.cloth.cache.VertexCache`; a missing cache is a one-line PrtError."""
    from prt_torch.cloth.cache import VertexCache

    path = simulation_path(cfg) if path is None else path
    if not path.exists():
        raise PrtError(f"{path}: no vertex cache for the cloth run {cfg.name!r}: run `prt simulate CONFIG` "
                       f"(or `prt bake CONFIG`, which simulates first)")
    return VertexCache(path)


def missing_sequences(cfg: RunConfig, subject: Any | None = None) -> list[str]:
    """The sequences of the run (train then held-out) that its vertex cache lacks (all of them without a cache)."""
    subject = load_subject(cfg) if subject is None else subject
    wanted = [*subject.sequences("train"), *subject.sequences("heldout")]
    path = simulation_path(cfg)
    if not path.exists():
        return wanted
    try:
        have = set(open_cache(cfg, path).sequences())
    except (StaleArtifact, DamagedArtifact):
        return wanted
    return [s for s in wanted if s not in have]


def sequence_frames(cfg: RunConfig, subject: Any, cache: Any, name: str) -> CachedSequence:
    """A cached sequence's checked positions and its pose features (:func:`prt_torch.cloth.inputs.cloth_features`
    of every frame, the body's pose features appended when ``cloth.append_pose``)."""
    from prt_torch.cloth.inputs import cloth_features

    if name not in set(cache.sequences()):
        raise PrtError(f"sequence {name!r} is not in the vertex cache {simulation_path(cfg)} (has: "
                       f"{sorted(cache.sequences())}); run `prt simulate CONFIG`")
    what = f"vertex cache sequence {name!r}"
    pos = check_positions(cache.positions(name), subject.character.num_vertices, what)
    body = None
    if bool(getattr(cfg.cloth, "append_pose", False)):
        body = cache.body_features(name)
        if body is None:
            raise PrtError(f"{what}: cloth.append_pose is set but the cache has no body features")
        body = np.asarray(body, dtype=np.float32)
        if body.shape[0] != pos.shape[0] or not np.isfinite(body).all():
            raise PrtError(f"{what}: body features of shape {body.shape} (non-finite or not one row per frame)")
    feats = np.asarray(cloth_features(pos, subject.cloth_edges, body), dtype=np.float32)
    if feats.shape[0] != pos.shape[0] or not np.isfinite(feats).all():
        raise PrtError(f"{what}: pose features of shape {feats.shape} are not finite per frame")
    return CachedSequence(name=name, positions=pos, features=feats)


def ensure_simulated(cfg: RunConfig, progress: bool = True) -> list[str]:
    """Simulate the sequences the run's vertex cache lacks (:func:`prt_torch.cloth.simulate.simulate`, resumable:
    finished sequences are kept, and a cache simulated with another configuration is refused); returns the names
    that were missing. No simulator (MuJoCo not installed) with a missing sequence is a one-line
    :class:`PrtError`; with a complete cache the bake goes on without it."""
    missing = missing_sequences(cfg)
    try:
        from prt_torch.cloth.simulate import simulate

        simulate(cfg, progress=progress and bool(missing))
    except ModuleNotFoundError as exc:
        if not missing:
            return []
        raise PrtError(f"cloth run {cfg.name!r}: the vertex cache {simulation_path(cfg)} lacks {len(missing)} "
                       f"sequence(s) ({', '.join(missing[:4])}) and the simulator cannot run ({exc.name or exc} "
                       f"not installed: pip install 'prt-torch[cloth]')") from None
    still = missing_sequences(cfg)
    if still:
        raise PrtError(f"cloth run {cfg.name!r}: the simulation left {len(still)} sequence(s) missing: "
                       f"{', '.join(still[:4])}")
    return missing


def make_deformable_plan(cfg: RunConfig, subject: Any | None = None, cache: Any | None = None) -> BakePlan:
    """The plan of a cloth run (``cloth:`` section) from its vertex cache: one dataset clip per cached sequence
    (``ClothSubject.sequences("train")`` then ``("heldout")``, splits from the cloth config), ``frame_index`` the
    frame within the sequence, ``pose`` the deformable input features, ``skin`` the identity, ``positions`` the
    cached positions (:func:`sequence_frames`). A missing cache or sequence, NaN positions or a wrong vertex
    count is a one-line :class:`PrtError`."""
    from prt_torch.bake.plan import BakePlan

    subject = load_subject(cfg) if subject is None else subject
    cache = open_cache(cfg) if cache is None else cache
    splits = {"train": list(subject.sequences("train")), "heldout": list(subject.sequences("heldout"))}
    names = splits["train"] + splits["heldout"]
    if not splits["train"]:
        raise PrtError(f"cloth run {cfg.name!r}: no training sequence")
    if len(set(names)) != len(names):
        raise PrtError(f"cloth run {cfg.name!r}: a sequence is both a training and a held-out one: {names}")
    seqs = [sequence_frames(cfg, subject, cache, n) for n in names]
    widths = {s.features.shape[1] for s in seqs}
    if len(widths) != 1:
        raise PrtError(f"cloth run {cfg.name!r}: sequences with different feature widths {sorted(widths)}")
    clip_id = np.concatenate([np.full(len(s.positions), i, np.int32) for i, s in enumerate(seqs)])
    frame_index = np.concatenate([np.arange(len(s.positions), dtype=np.int32) for s in seqs])
    positions = np.concatenate([s.positions for s in seqs]).astype(np.float32)
    skin = np.broadcast_to(np.eye(4), (len(clip_id), 1, 4, 4)).copy()
    return BakePlan(character=subject.character, clip_names=names, splits=splits, clip_id=clip_id,
                    frame_index=frame_index, pose=np.concatenate([s.features for s in seqs]).astype(np.float32),
                    skin=skin, positions=positions)


#: the cloth's entry of :data:`prt_torch.bake.deformable.SUBJECTS` (a run with a ``cloth:`` section)
def read_sequence(cfg: RunConfig, name: str) -> CachedSequence:
    """The cached sequence ``name`` of the run config ``cfg`` (its subject and vertex cache), for ``prt compare
    --clip``: :func:`sequence_frames`."""
    return sequence_frames(cfg, load_subject(cfg), open_cache(cfg), name)


SOURCE = DeformableSource(section="cloth", prepare=ensure_simulated, plan=make_deformable_plan, read=read_sequence)
