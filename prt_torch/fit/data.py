"""Read the frames of a split from a baked ``dataset.zarr`` (layout: docs/DESIGN.md).

Only completed frames (``done``) of the split's clips are used, in stored order. Arrays come
back as numpy: ``pose (F, A)`` float32, ``visibility (F, V, C)`` float32 (local frame), and on
request ``positions``/``normals`` ``(F, V, 3)`` and ``frames (F, V, 3, 3)`` (rows t, b, n).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check

REQUIRED = ("pose", "visibility", "clip_id", "frame_index", "cluster")


@dataclass
class DatasetInfo:
    """Dataset-wide arrays and attributes."""

    path: Path
    attrs: dict[str, Any]
    clip_names: list[str]
    splits: dict[str, list[str]]
    cluster: np.ndarray  # (V,) int
    faces: np.ndarray  # (T, 3) int
    n_vertices: int
    n_coeffs: int
    n_features: int

    @property
    def order(self) -> int:
        return int(round(self.n_coeffs**0.5))

    @property
    def character_hash(self) -> str:
        return str(self.attrs.get("character_hash", ""))


@dataclass
class SplitData:
    """The completed frames of one split (``train`` or ``heldout``)."""

    name: str
    pose: np.ndarray  # (F, A) float32
    visibility: np.ndarray  # (F, V, C) float32
    clip_id: np.ndarray  # (F,) int
    frame_index: np.ndarray  # (F,) int
    clips: list[str]
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.pose.shape[0])


def _open(path: str | Path):  # noqa: ANN202 - zarr.Group
    import zarr

    path = Path(path)
    if not path.exists():
        raise PrtError(f"dataset not found: {path}")
    try:
        g = zarr.open_group(str(path), mode="r")
    except Exception as exc:  # noqa: BLE001
        raise PrtError(f"{path}: not a zarr dataset ({type(exc).__name__})") from None
    for name in REQUIRED:
        if name not in g:
            raise PrtError(f"{path}: dataset has no '{name}' array")
    return g


def dataset_info(path: str | Path) -> DatasetInfo:
    """Attributes and the per-vertex/per-mesh arrays of a dataset."""
    g = _open(path)
    attrs = dict(g.attrs)
    vis = g["visibility"]
    check(len(vis.shape) == 3, f"{path}: visibility must be (F, V, C), got {vis.shape}")
    clip_names = list(attrs.get("clip_names", []))
    splits = {k: list(v) for k, v in dict(attrs.get("splits", {})).items()}
    faces = np.asarray(g["faces"][:]) if "faces" in g else np.zeros((0, 3), np.int64)
    return DatasetInfo(path=Path(path), attrs=attrs, clip_names=clip_names, splits=splits,
                       cluster=np.asarray(g["cluster"][:]), faces=faces, n_vertices=int(vis.shape[1]),
                       n_coeffs=int(vis.shape[2]), n_features=int(g["pose"].shape[1]))


def load_split(path: str | Path, split: str, extra: tuple[str, ...] = (),
               max_frames: int | None = None, contiguous: bool = False) -> SplitData:
    """Frames of ``split`` (a key of the ``splits`` attribute) that are baked (``done``).

    ``extra`` names further per-frame arrays to load (``positions``, ``normals``, ``frames``,
    ``transfer``); ``max_frames`` keeps an evenly strided subset (for quick evaluation), or with
    ``contiguous`` the first ``max_frames / n_clips`` consecutive frames of each clip (so
    frame-to-frame measures stay meaningful).
    """
    g = _open(path)
    info = dataset_info(path)
    if split not in info.splits:
        raise PrtError(f"{path}: no split '{split}' (have {sorted(info.splits)})")
    wanted = [info.clip_names.index(c) for c in info.splits[split] if c in info.clip_names]
    clip_id = np.asarray(g["clip_id"][:])
    sel = np.isin(clip_id, wanted)
    if "done" in g:
        sel &= np.asarray(g["done"][:], dtype=bool)
    idx = np.flatnonzero(sel)
    if len(idx) == 0:
        raise PrtError(f"{path}: split '{split}' has no baked frames")
    if max_frames is not None and len(idx) > max_frames:
        if contiguous:
            ids = clip_id[idx]
            per = max(2, -(-max_frames // len(np.unique(ids))))
            keep = np.concatenate([idx[ids == c][:per] for c in np.unique(ids)])
            idx = np.sort(keep)
        else:
            idx = idx[np.linspace(0, len(idx) - 1, max_frames).round().astype(np.int64)]
    pose = np.asarray(g["pose"].oindex[idx], dtype=np.float32)
    vis = np.asarray(g["visibility"].oindex[idx], dtype=np.float32)
    check(bool(np.isfinite(pose).all()), f"{path}: pose features of split '{split}' contain NaN or Inf")
    check(bool(np.isfinite(vis).all()), f"{path}: visibility of split '{split}' contains NaN or Inf")
    out = {}
    for name in extra:
        if name not in g:
            raise PrtError(f"{path}: dataset has no '{name}' array")
        out[name] = np.asarray(g[name].oindex[idx])
    return SplitData(name=split, pose=pose, visibility=vis, clip_id=clip_id[idx],
                     frame_index=np.asarray(g["frame_index"].oindex[idx]),
                     clips=[info.clip_names[i] for i in wanted], extra=out)
