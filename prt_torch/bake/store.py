"""The baked dataset: a zarr v3 directory ``runs/NAME/dataset.zarr`` (layout in docs/DESIGN.md).

Per-frame arrays are chunked by ``frames_per_task`` frames along the first axis, so that every
task of the runner writes whole chunks that no other task touches (concurrent writers of one
chunk corrupt it: zarr-python #2729, #3682). A task writes its data arrays first and sets its
``done`` entries last; zarr's LocalStore writes each chunk atomically (temporary file + rename),
so a SIGKILL at any moment loses only the blocks in flight.

The store is created complete (every array, the static arrays, the attributes) in a temporary
sibling directory and renamed into place; opening an existing store first compares its
attributes with the new bake and raises :class:`PrtError` naming the first difference, without
writing anything.

Arrays (``F`` frames, ``V`` vertices, ``C = order**2``, ``C6 = transfer_order**2``, ``Kc``
clusters): ``pose (F, A)``, ``visibility (F, V, C)`` local frame, ``transfer (F, V, C6)`` world
frame (optional), ``positions``/``normals (F, V, 3)`` world, ``frames (F, V, 3, 3)`` rows
``(t, b, n)``, ``clip_id``/``frame_index (F,)`` int32, ``done (F,)`` bool, ``faces (T, 3)`` int32,
``cluster (V,)`` int32, ``cluster_axis (Kc, 3)`` float32 rest-pose cluster axes, ``cluster_bone
(Kc,)`` int32 dominant bones (``prt_torch.rig.vertex_frames.vertex_frames`` rebuilds the frames from
these three and the posed normals/skin).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import PrtError

if TYPE_CHECKING:
    from prt_torch.rig.character import Character

FORMAT_VERSION = 1

#: per-frame float arrays written by the bake tasks, with their per-frame shapes
PER_FRAME_RESULTS = ("positions", "normals", "frames", "visibility", "transfer")

#: attrs["bake"] keys that change the baked numbers (compared on resume)
RESULT_KEYS = ("order", "n_rays", "transfer", "transfer_order", "bounces", "albedo", "seed", "ray_offset",
               "cluster_bandwidth", "max_clusters", "min_cluster_size")

CONVENTIONS = {
    "world": "right-handed, z up",
    "sh": "real orthonormal SH, index l*(l+1)+m, no Condon-Shortley phase (Ramamoorthi-Hanrahan 2001)",
    "frames": "rows (t, b, n) in world coordinates; local coordinates of world w are F @ w; local +z = normal",
    "visibility": "SH over the whole sphere of V(s) = 0 if the ray hits the mesh or s.n < 0, else 1; local frame",
    "transfer": "world frame, int V(w) max(n.w, 0)/pi y(w) dw plus interreflection bounces; shade albedo * (L . t)",
    "rays": "shared spherical-Fibonacci hemisphere set rotated per vertex about n by a fixed seeded angle",
}



def library_versions() -> dict[str, str]:
    """Versions of the libraries that determine the baked numbers."""
    import importlib.metadata as md

    out = {}
    for name in ("prt-torch", "numpy", "scipy", "scikit-learn", "embreex", "zarr", "trimesh"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "unknown"
    return out


def create_store(path: Path, arrays: dict[str, np.ndarray], per_frame: dict[str, tuple[tuple[int, ...], str]],
                 n_frames: int, frames_per_task: int, attrs: dict[str, Any]) -> None:
    """Create a complete store atomically (temporary sibling directory, then rename).

    Args:
        path: the ``dataset.zarr`` directory to create (must not exist).
        arrays: arrays written whole at creation (frame-indexed ones, e.g. ``pose``, are chunked
            by ``frames_per_task`` along axis 0 when their first axis has length ``n_frames``).
        per_frame: result arrays to create empty: name -> (per-frame shape, dtype); filled by tasks.
        n_frames: ``F``.
        frames_per_task: chunk length along the frame axis.
        attrs: group attributes (JSON-serialisable).
    """
    import zarr

    if path.exists():
        raise PrtError(f"dataset already exists: {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in path.parent.glob(f".{path.name}.tmp-*"):  # left by a creation that was killed
        shutil.rmtree(stale, ignore_errors=True)
    tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:8]}"
    try:
        g = zarr.open_group(str(tmp), mode="w-", zarr_format=3)
        for name, (shape, dtype) in per_frame.items():
            g.create_array(name, shape=(n_frames, *shape), chunks=(frames_per_task, *shape), dtype=dtype,
                           fill_value=0)
        g.create_array("done", shape=(n_frames,), chunks=(frames_per_task,), dtype=bool, fill_value=False)
        for name, a in arrays.items():
            if a.ndim >= 1 and a.shape[0] == n_frames and name not in ("faces", "cluster"):
                chunks = (frames_per_task, *a.shape[1:])
            else:
                chunks = a.shape if a.size else tuple(max(1, s) for s in a.shape)
            g.create_array(name, data=a, chunks=chunks)
        g.attrs.update(attrs)
        os.replace(tmp, path)  # atomic for a fresh target on POSIX (fails if path appeared meanwhile)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def check_compatible(path: Path, attrs: dict[str, Any], existing: dict[str, Any]) -> None:
    """Raise :class:`PrtError` naming the first difference between a store's attributes and a new bake."""
    if existing.get("format_version") != FORMAT_VERSION:
        raise PrtError(f"{path}: not a prt_torch dataset of format {FORMAT_VERSION}; move it away or delete it")
    if existing.get("character_hash") != attrs["character_hash"]:
        raise PrtError(f"{path} was baked from another character (hash {str(existing.get('character_hash'))[:12]} "
                       f"!= {attrs['character_hash'][:12]}); nothing written")
    old_bake, new_bake = existing.get("bake", {}), attrs["bake"]
    for key in RESULT_KEYS:
        if old_bake.get(key) != new_bake.get(key):
            raise PrtError(f"{path} was baked with bake.{key}={old_bake.get(key)!r}, the config has "
                           f"{new_bake.get(key)!r}; nothing written")
    if existing.get("frames_fingerprint") != attrs["frames_fingerprint"]:
        raise PrtError(f"{path} holds a different frame list (clips, fps, random poses); nothing written")


@dataclass
class SplitData:
    """The completed frames of one split (``train`` or ``heldout``), in stored order.

    ``pose (F, A)`` float32, ``visibility (F, V, C)`` float32 (local frame), ``clip_id`` /
    ``frame_index (F,)`` int, ``rows (F,)`` their dataset rows, ``clips`` the split's clip names and
    ``extra`` the further per-frame arrays asked for (``positions``, ``normals``, ``frames``, ``transfer``).
    """

    name: str
    pose: np.ndarray
    visibility: np.ndarray
    clip_id: np.ndarray
    frame_index: np.ndarray
    clips: list[str]
    rows: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.pose.shape[0])


class BakedDataset:
    """Read access to a baked ``dataset.zarr`` (numpy arrays, read when asked for): the only dataset reader.

    Small arrays (``pose``, ``clip_id``, ``faces``, ``cluster``, ...) are cached; the big per-frame
    ones (``visibility``, ``transfer``, ``positions``, ``normals``, ``frames``) are read anew on
    every access; use :meth:`array` for zarr slicing without reading everything.
    """

    def __init__(self, path: Path, validate: bool = True) -> None:
        import zarr

        self.path = Path(path)
        if not self.path.exists():
            raise PrtError(f"dataset not found: {self.path}")
        try:
            self._group = zarr.open_group(str(self.path), mode="r")
        except Exception as exc:
            raise PrtError(f"{self.path}: not a zarr dataset ({type(exc).__name__})") from None
        self.attrs: dict[str, Any] = dict(self._group.attrs)
        if not validate:
            return
        for name in ("pose", "visibility", "clip_id", "frame_index", "done", "cluster"):
            if name not in self._group:
                raise PrtError(f"{self.path}: dataset has no '{name}' array")
        for key in ("clip_names", "splits", "sh_order"):
            if key not in self.attrs:
                raise PrtError(f"{self.path}: dataset has no '{key}' attribute")

    # -- metadata ------------------------------------------------------------------------------
    @property
    def clip_names(self) -> list[str]:
        return list(self.attrs["clip_names"])

    @property
    def splits(self) -> dict[str, list[str]]:
        return {k: list(v) for k, v in dict(self.attrs["splits"]).items()}

    @property
    def sh_order(self) -> int:
        return int(self.attrs["sh_order"])

    @property
    def n_rays(self) -> int:
        return int(self.attrs.get("n_rays", 0))

    @property
    def character_hash(self) -> str:
        return str(self.attrs.get("character_hash", ""))

    @property
    def n_frames(self) -> int:
        return int(self._group["visibility"].shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self._group["visibility"].shape[1])

    @property
    def n_coeffs(self) -> int:
        return int(self._group["visibility"].shape[2])

    @property
    def n_features(self) -> int:
        return int(self._group["pose"].shape[1])

    @property
    def order(self) -> int:
        """SH order of the visibility (``C = order**2``)."""
        return int(round(self.n_coeffs**0.5))

    def array(self, name: str) -> Any:
        """The zarr array ``name`` (for sliced reads)."""
        if name not in self._group:
            raise PrtError(f"{self.path}: dataset has no '{name}' array")
        return self._group[name]

    def __contains__(self, name: str) -> bool:
        return name in self._group

    # -- small arrays (cached) ----------------------------------------------------------------
    @cached_property
    def pose(self) -> np.ndarray:
        """``(F, A)`` float32 pose features."""
        return np.asarray(self._group["pose"][:])

    @cached_property
    def clip_id(self) -> np.ndarray:
        """``(F,)`` int32."""
        return np.asarray(self._group["clip_id"][:])

    @cached_property
    def frame_index(self) -> np.ndarray:
        """``(F,)`` int32."""
        return np.asarray(self._group["frame_index"][:])

    @cached_property
    def faces(self) -> np.ndarray:
        """``(T, 3)`` int32."""
        return np.asarray(self._group["faces"][:])

    @cached_property
    def cluster(self) -> np.ndarray:
        """``(V,)`` int32 local-frame cluster of each vertex."""
        return np.asarray(self._group["cluster"][:])

    @cached_property
    def cluster_axis(self) -> np.ndarray:
        """``(Kc, 3)`` float32 rest-pose PCA axis of each cluster."""
        return np.asarray(self.array("cluster_axis")[:])

    @cached_property
    def cluster_bone(self) -> np.ndarray:
        """``(Kc,)`` int32 dominant bone of each cluster."""
        return np.asarray(self.array("cluster_bone")[:])

    @property
    def done(self) -> np.ndarray:
        """``(F,)`` bool completion mask (read fresh: a bake may be running)."""
        return np.asarray(self._group["done"][:], dtype=bool)

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    # -- per-frame arrays (read on access) ----------------------------------------------------
    @property
    def visibility(self) -> np.ndarray:
        """``(F, V, C)`` float32 local-frame SH visibility."""
        return np.asarray(self._group["visibility"][:])

    @property
    def transfer(self) -> np.ndarray | None:
        """``(F, V, C6)`` float32 world-frame diffuse transfer, or None if not baked."""
        return np.asarray(self._group["transfer"][:]) if "transfer" in self._group else None

    @property
    def positions(self) -> np.ndarray:
        """``(F, V, 3)`` float32 posed positions (world)."""
        return np.asarray(self._group["positions"][:])

    @property
    def normals(self) -> np.ndarray:
        """``(F, V, 3)`` float32 posed unit normals (world)."""
        return np.asarray(self._group["normals"][:])

    @property
    def frames(self) -> np.ndarray:
        """``(F, V, 3, 3)`` float32 vertex frames, rows ``(t, b, n)``."""
        return np.asarray(self._group["frames"][:])

    # -- splits --------------------------------------------------------------------------------
    def clip_mask(self, name: str) -> np.ndarray:
        """``(F,)`` bool frames of clip ``name``."""
        if name not in self.clip_names:
            raise PrtError(f"{self.path}: no clip {name!r} (have {self.clip_names})")
        return self.clip_id == self.clip_names.index(name)

    def split_mask(self, split: str) -> np.ndarray:
        """``(F,)`` bool frames of a split (``train`` or ``heldout``)."""
        if split not in self.splits:
            raise PrtError(f"{self.path}: no split {split!r} (have {sorted(self.splits)})")
        ids = [self.clip_names.index(c) for c in self.splits[split]]
        return np.isin(self.clip_id, ids)

    def key(self) -> str:
        """The up-to-date key of this dataset's content: frame list, character, bake settings, done count."""
        from prt_torch.rundir import stage_key

        a = self.attrs
        return stage_key({"fingerprint": a.get("frames_fingerprint"), "character_hash": a.get("character_hash"),
                          "bake": a.get("bake"), "done": int(self.done.sum())})

    def split_rows(self, split: str) -> np.ndarray:
        """``(F_split,)`` int64 dataset rows of the DONE frames of ``split``, in stored order."""
        return np.flatnonzero(self.split_mask(split) & self.done)

    def clip_rows(self, clip: str) -> np.ndarray:
        """``(F_clip,)`` int64 dataset rows of the DONE frames of clip ``clip``."""
        return np.flatnonzero(self.clip_mask(clip) & self.done)

    def rows(self, rows: np.ndarray, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Per-frame arrays ``names`` at dataset ``rows`` (one orthogonal zarr read each)."""
        rows = np.asarray(rows, dtype=np.int64)
        out = {}
        for name in names:
            a = self.array(name)
            out[name] = np.asarray(a.get_orthogonal_selection((rows,) + (slice(None),) * (len(a.shape) - 1)))
        return out

    def split(self, split: str, extra: tuple[str, ...] = (), max_frames: int | None = None,
              contiguous: bool = False, rows: np.ndarray | None = None) -> SplitData:
        """The done frames of ``split`` (a key of the ``splits`` attribute).

        ``extra`` names further per-frame arrays to read (``positions``, ``normals``, ``frames``,
        ``transfer``). ``max_frames`` keeps an evenly strided subset, or with ``contiguous`` the first
        ``ceil(max_frames / n_clips)`` consecutive frames of each clip (frame-to-frame measures stay
        meaningful); ``None`` keeps every frame. ``rows``: use these dataset rows instead.
        """
        idx = self.split_rows(split) if rows is None else np.asarray(rows, dtype=np.int64)
        if len(idx) == 0:
            raise PrtError(f"{self.path}: split '{split}' has no baked frames")
        clip_id = self.clip_id
        if max_frames is not None and len(idx) > max_frames:
            if contiguous:
                ids = clip_id[idx]
                per = max(2, -(-max_frames // len(np.unique(ids))))
                idx = np.sort(np.concatenate([idx[ids == c][:per] for c in np.unique(ids)]))
            else:
                idx = idx[np.linspace(0, len(idx) - 1, max_frames).round().astype(np.int64)]
        data = self.rows(idx, ("pose", "visibility", *extra))
        pose = data.pop("pose").astype(np.float32)
        vis = data.pop("visibility").astype(np.float32)
        if not np.isfinite(pose).all():
            raise PrtError(f"{self.path}: pose features of split '{split}' contain NaN or Inf")
        if not np.isfinite(vis).all():
            raise PrtError(f"{self.path}: visibility of split '{split}' contains NaN or Inf")
        names = self.splits.get(split, [])
        return SplitData(name=split, pose=pose, visibility=vis, clip_id=clip_id[idx], frame_index=self.frame_index[idx],
                         clips=[c for c in names if c in self.clip_names], rows=idx, extra=data)

    @property
    def train_mask(self) -> np.ndarray:
        """``(F,)`` bool training frames."""
        return self.split_mask("train")

    @property
    def heldout_mask(self) -> np.ndarray:
        """``(F,)`` bool held-out frames."""
        return self.split_mask("heldout")

    def character(self) -> Character:
        """The baked character of the run directory holding the dataset (hash-checked)."""
        from prt_torch.rundir import RunDir

        return RunDir(self.path).character(expect_hash=self.character_hash or None)

    def __repr__(self) -> str:
        return (f"BakedDataset({str(self.path)!r}, frames={self.n_frames}, vertices={self.n_vertices}, "
                f"order={self.sh_order}, done={int(self.done.sum())}/{self.n_frames})")


def open_dataset(path: str | os.PathLike[str]) -> BakedDataset:
    """Open a baked dataset store for reading (a run directory holding one is accepted too)."""
    from prt_torch.rundir import RunDir

    p = Path(path)
    if p.is_dir() and not (p / "zarr.json").exists() and RunDir(p).dataset_path.is_dir():
        p = RunDir(p).dataset_path
    if not p.exists():
        raise PrtError(f"dataset not found: {p}")
    return BakedDataset(p)


def open_for_writing(path: Path) -> Any:
    """The store's zarr group opened for the bake's block writes (``r+``; the bake runner only)."""
    import zarr

    try:
        return zarr.open_group(str(path), mode="r+")
    except Exception as exc:
        raise PrtError(f"{path}: not a zarr dataset ({type(exc).__name__})") from None


def remove_partial_files(path: Path) -> None:
    """Delete ``*.partial`` leftovers of chunk writes interrupted by a kill (zarr's atomic writes)."""
    for f in path.rglob("*.partial"):
        with contextlib.suppress(FileNotFoundError):
            f.unlink()
