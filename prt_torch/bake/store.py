"""The baked dataset: a zarr v3 directory ``runs/NAME/dataset.zarr`` (layout in docs/DESIGN.md).

Per-frame arrays are chunked by ``frames_per_task`` frames along the first axis, so that every
task of the runner writes whole chunks that no other task touches (concurrent writers of one
chunk corrupt it: zarr-python #2729, #3682). A task writes its data arrays first and sets its
``done`` entries last; zarr's LocalStore writes each chunk atomically (temporary file + rename),
so a SIGKILL at any moment loses only the blocks in flight.

The store is created complete (every array, the static arrays, the attributes) in a temporary
sibling directory and renamed into place without replacing anything (the bake holds the run
directory's lock, :meth:`prt_torch.rundir.RunDir.lock`, while it creates or resumes a store);
opening an existing store first compares its attributes with the new bake and raises
:class:`PrtError` naming the first difference, without writing anything.

Integrity (format 2): every chunk of every array ends in a crc32c checksum (zarr v3's ``crc32c``
codec after zstd), and every chunk is written even when it equals the fill value, so a chunk of a
done block (or of a creation-time array) that is missing on disk is damage, not zeros.
:meth:`BakedDataset.verify` lists the missing chunks (cheap: one ``stat`` per chunk) and, with
``checksums=True``, the chunks that fail to decode; the readers (:meth:`BakedDataset.rows`,
:meth:`BakedDataset.split`, the array properties) turn either into a one-line :class:`PrtError`
naming the array and the frames, and ``prt bake`` re-bakes the damaged blocks. Format 1 stores
(no checksums, fill-valued chunks not written) are still read and resumed; for them only the
per-frame result arrays are checked for missing chunks.

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
import ctypes
import errno
import itertools
import os
import shutil
import sys
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.bake.config import BakeConfig, absent_values, recorded_keys, result_keys
from prt_torch.errors import DamagedArtifact, MissingArtifact, PrtError, StaleArtifact
from prt_torch.metrics import evenly_spaced_indices

if TYPE_CHECKING:
    from prt_torch.config import RunConfig
    from prt_torch.rig.character import Character
    from prt_torch.rig.load import PlanClip

#: the layout written by this code: 2 = crc32c on every chunk, every chunk written (1: neither)
FORMAT_VERSION = 2
#: store formats this code reads and resumes
READABLE_FORMATS = (1, 2)

#: per-frame float arrays written by the bake tasks, with their per-frame shapes
PER_FRAME_RESULTS = ("positions", "normals", "frames", "visibility", "transfer", "transfer_matrix", "subsurface",
                     "peak_directions", "peak_visibility")

#: attrs["bake"] keys that change the baked numbers (compared on resume): the BakeConfig fields marked ``result``
RESULT_KEYS = result_keys()
#: the value of a recorded key added after stores were written, for a store that does not record it (the schema's
#: ``absent`` marks, :func:`prt_torch.bake.config.absent_values`)
RESULT_KEY_DEFAULTS = absent_values()

#: the visibility convention text of each ``bake.below_horizon``
VISIBILITY_CONVENTIONS = {
    "zero": "SH over the whole sphere of V(s) = 0 if the ray hits the mesh or s.n < 0, else 1; local frame",
    "one": "SH over the whole sphere of V(s) = 0 if the ray hits the mesh and s.n >= 0, else 1 (1 below the "
           "horizon, seed 003 eq. 1: an unoccluded vertex is the constant sqrt(4 pi) e_0); local frame",
}

CONVENTIONS = {
    "world": "right-handed, z up",
    "sh": "real orthonormal SH, index l*(l+1)+m, no Condon-Shortley phase (Ramamoorthi-Hanrahan 2001)",
    "frames": "rows (t, b, n) in world coordinates; local coordinates of world w are F @ w; local +z = normal",
    "visibility": VISIBILITY_CONVENTIONS["zero"],
    "below_horizon": "zero",
    "transfer": "world frame, int V(w) max(n.w, 0)/pi y(w) dw plus interreflection bounces; shade albedo * (L . t)",
    "rays": "shared spherical-Fibonacci hemisphere set rotated per vertex about n by a fixed seeded angle",
}


def conventions(below_horizon: str = "zero") -> dict[str, str]:
    """The ``conventions`` attribute of a store baked with ``bake.below_horizon = below_horizon``."""
    if below_horizon not in VISIBILITY_CONVENTIONS:
        raise PrtError(f"below_horizon must be one of {sorted(VISIBILITY_CONVENTIONS)}, got {below_horizon!r}")
    return {**CONVENTIONS, "visibility": VISIBILITY_CONVENTIONS[below_horizon], "below_horizon": below_horizon}


def recorded_config(attrs: Any) -> dict[str, Any]:
    """The run config a store's attributes record (``attrs["config"]``, the bake's config as a plain dict; ``{}``
    when absent): the one way to read it (:meth:`BakedDataset.recorded_config`)."""
    cfg = (attrs or {}).get("config") or {}
    return dict(cfg) if isinstance(cfg, dict) else {}


def recorded_run_config(attrs: Any, source: str = "dataset") -> RunConfig | None:
    """The run config a store records (``attrs["config"]``), validated as a :class:`prt_torch.config.RunConfig`
    (a field an older config lacks takes its default), its ``bake`` section the settings the store was baked with
    (:func:`recorded_bake_config`); ``None`` when the store records none. A recorded config that is not a mapping
    is a :class:`DamagedArtifact`, one that does not validate a :class:`StaleArtifact` (one line naming the key).
    ``source`` names the store in the message."""
    from prt_torch.config import config_from_dict

    raw = (attrs or {}).get("config")
    if raw is None or raw == {}:
        return None
    if not isinstance(raw, dict):
        raise DamagedArtifact(f"{source}: the recorded run config is a {type(raw).__name__}, not a mapping")
    bake = recorded_bake_config(attrs, source)
    try:
        return config_from_dict({**raw, "bake": bake}, source=f"{source} (recorded run config)")
    except PrtError as exc:
        raise StaleArtifact(f"{exc}: not a config this version reads; re-bake the run") from None


def recorded_bake_config(attrs: Any, source: str = "dataset") -> BakeConfig:
    """The bake settings a store was baked with, validated as a :class:`prt_torch.bake.config.BakeConfig`: the
    recorded ``attrs["bake"]`` (its :func:`~prt_torch.bake.config.recorded_keys`; a key a store written before it
    was recorded lacks takes its :func:`~prt_torch.bake.config.absent_values` value) over the recorded config's
    ``bake`` section (the settings the store does not record there, e.g. ``blockers``), schema defaults for the
    rest. A recorded ``bake`` that is not a mapping is a :class:`DamagedArtifact`, one that does not validate a
    :class:`StaleArtifact` (one line naming the key)."""
    from pydantic import ValidationError

    from prt_torch.config import validation_message

    attrs = attrs or {}
    section = recorded_config(attrs).get("bake") or {}
    bake = attrs.get("bake") or {}
    if not (isinstance(section, dict) and isinstance(bake, dict)):
        raise DamagedArtifact(f"{source}: the recorded bake settings are not a mapping")
    data = {**section, **absent_values(), **{k: bake[k] for k in recorded_keys() if k in bake}}
    try:
        return BakeConfig.model_validate(data)
    except ValidationError as exc:
        msg = validation_message(exc, f"{source} (recorded bake settings)")
        raise StaleArtifact(f"{msg}: not a config this version reads; re-bake the run") from None


def recorded_fps(attrs: Any) -> float | None:
    """The frame rate the bake posed the clips at (the recorded ``character.fps``; None: each clip's own)."""
    return (recorded_config(attrs).get("character") or {}).get("fps")


def below_horizon_of(attrs: dict[str, Any] | None) -> str:
    """The ``bake.below_horizon`` convention of a store's (or a compare run's bake) attributes: ``"zero"`` for
    stores written before it was recorded; a one-line :class:`PrtError` for an unknown value."""
    attrs = attrs or {}
    bake = attrs.get("bake", attrs)  # the store attributes, or their "bake" dict itself
    value = (bake or {}).get("below_horizon", RESULT_KEY_DEFAULTS["below_horizon"])
    if value not in VISIBILITY_CONVENTIONS:
        raise PrtError(f"dataset records bake.below_horizon={value!r}, expected one of "
                       f"{sorted(VISIBILITY_CONVENTIONS)}")
    return str(value)

#: arrays with one entry per frame that are written at creation (the rest of the frame arrays are
#: ``PER_FRAME_RESULTS`` and ``done``, written by the bake tasks)
FRAME_STATIC = ("pose", "clip_id", "frame_index")
#: arrays a re-bake of their damaged blocks repairs
REBAKED = (*PER_FRAME_RESULTS, "done")
#: what a damage message tells the user to do
REPAIR_HINT = "re-run `prt bake` with this run's config to repair it"


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


def store_codecs() -> dict[str, Any]:
    """``create_array`` keyword arguments of format 2: zstd (zarr's default, level 0), then a crc32c checksum."""
    from zarr.codecs import Crc32cCodec, ZstdCodec

    return {"compressors": [ZstdCodec(level=0), Crc32cCodec()], "config": {"write_empty_chunks": True}}


def _rename_noreplace(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst`` atomically, failing with ``FileExistsError`` when ``dst`` exists.

    Linux: ``renameat2(RENAME_NOREPLACE)``; elsewhere (or where the call is unsupported) an existence
    check then ``os.rename``, which still never replaces a non-empty directory.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            renameat2 = libc.renameat2
        except (OSError, AttributeError):
            renameat2 = None
        if renameat2 is not None:
            at_fdcwd, rename_noreplace = -100, 1
            if renameat2(at_fdcwd, os.fsencode(src), at_fdcwd, os.fsencode(dst), rename_noreplace) == 0:
                return
            err = ctypes.get_errno()
            if err == errno.EEXIST:
                raise FileExistsError(err, os.strerror(err), str(dst))
            if err not in (errno.ENOSYS, errno.EINVAL):  # EINVAL: a file system without RENAME_NOREPLACE
                raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
    os.rename(src, dst)


def create_store(path: Path, arrays: dict[str, np.ndarray], per_frame: dict[str, tuple[tuple[int, ...], str]],
                 n_frames: int, frames_per_task: int, attrs: dict[str, Any]) -> None:
    """Create a complete store atomically (temporary sibling directory, then a rename that replaces nothing).

    The caller holds the run directory's lock (:meth:`prt_torch.rundir.RunDir.lock`): only the holder
    removes temporary stores left by a killed creation, so concurrent bakes never delete each other's.

    Args:
        path: the ``dataset.zarr`` directory to create (must not exist).
        arrays: arrays written whole at creation (frame-indexed ones, e.g. ``pose``, are chunked
            by ``frames_per_task`` along axis 0 when their first axis has length ``n_frames``).
        per_frame: result arrays to create empty: name -> (per-frame shape, dtype); filled by tasks.
        n_frames: ``F``.
        frames_per_task: chunk length along the frame axis.
        attrs: group attributes (JSON-serialisable; ``format_version`` says the layout).
    """
    if path.exists():
        raise PrtError(f"dataset already exists: {path}")
    codecs = store_codecs() if int(attrs.get("format_version", FORMAT_VERSION)) >= 2 else {}
    with new_store(path, "this bake", "run `prt bake` again to resume it") as g:
        for name, (shape, dtype) in per_frame.items():
            g.create_array(name, shape=(n_frames, *shape), chunks=(frames_per_task, *shape), dtype=dtype,
                           fill_value=0, **codecs)
        g.create_array("done", shape=(n_frames,), chunks=(frames_per_task,), dtype=bool, fill_value=False,
                       **codecs)
        for name, a in arrays.items():
            if a.ndim >= 1 and a.shape[0] == n_frames and name not in ("faces", "cluster"):
                chunks = (frames_per_task, *a.shape[1:])
            else:
                chunks = a.shape if a.size else tuple(max(1, s) for s in a.shape)
            g.create_array(name, data=a, chunks=chunks, **codecs)
        g.attrs.update(attrs)


@contextmanager
def new_store(path: Path, who: str, retry: str) -> Iterator[Any]:
    """Create a zarr v3 group atomically: yield a group in a temporary sibling directory (stale siblings left by a
    killed creation are removed first), then rename it to ``path`` with a rename that replaces nothing; on any
    error the temporary directory is removed. ``who``/``retry`` word the one-line error when ``path`` appeared
    meanwhile (e.g. ``"this bake"``, ``"run `prt bake` again to resume it"``). The caller holds the run
    directory's lock (only the holder removes stale temporaries). Used by the bake's dataset and the cloth's
    vertex cache."""
    import zarr

    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in path.parent.glob(f".{path.name}.tmp-*"):  # left by a creation that was killed
        shutil.rmtree(stale, ignore_errors=True)
    tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:8]}"
    try:
        yield zarr.open_group(str(tmp), mode="w-", zarr_format=3)
        try:
            _rename_noreplace(tmp, path)
        except FileExistsError:
            raise PrtError(f"{path} appeared while {who} was creating it; nothing overwritten: {retry}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Overwrite whole creation-time arrays of a store (repairs them; shapes must match)."""
    g = open_for_writing(path)
    for name, a in arrays.items():
        arr = writable(g[name])
        if tuple(arr.shape) != a.shape:
            raise PrtError(f"{path}: array '{name}' has shape {tuple(arr.shape)}, the bake has {a.shape}")
        arr[...] = a


def writable(a: Any) -> Any:
    """``a`` writing every chunk, fill-valued ones included (a missing chunk then always means damage)."""
    return a.with_config({"write_empty_chunks": True})


def check_compatible(path: Path, attrs: dict[str, Any], existing: dict[str, Any]) -> None:
    """Raise :class:`PrtError` naming the first difference between a store's attributes and a new bake."""
    if existing.get("format_version") not in READABLE_FORMATS:
        raise PrtError(f"{path}: not a prt_torch dataset of format {'/'.join(map(str, READABLE_FORMATS))}; "
                       "move it away or delete it")
    if existing.get("character_hash") != attrs["character_hash"]:
        raise PrtError(f"{path} was baked from another character (hash {str(existing.get('character_hash'))[:12]} "
                       f"!= {attrs['character_hash'][:12]}); nothing written")
    old_bake, new_bake = existing.get("bake", {}), attrs["bake"]
    for key in RESULT_KEYS:
        old, new = (b.get(key, RESULT_KEY_DEFAULTS.get(key)) for b in (old_bake, new_bake))
        if old != new:
            raise PrtError(f"{path} was baked with bake.{key}={old!r}, the config has {new!r}; nothing written")
    if existing.get("frames_fingerprint") != attrs["frames_fingerprint"]:
        raise PrtError(f"{path} holds a different frame list (clips, fps, random poses); nothing written")


@dataclass(frozen=True)
class Damage:
    """A damaged chunk of a store: array ``array``, frames ``[start, stop)`` (``None`` for an array
    without a frame axis), and what is wrong (``missing chunk`` or ``unreadable chunk (...)``)."""

    array: str
    start: int | None
    stop: int | None
    problem: str

    def where(self) -> str:
        """``array 'visibility' frames 8-11`` (or ``array 'faces'``)."""
        frames = "" if self.start is None or self.stop is None else f" frames {self.start}-{self.stop - 1}"
        return f"array '{self.array}'{frames}"

    def message(self, path: Path) -> str:
        """The one-line error of this damage, with the repair hint."""
        return f"{path}: {self.where()}: {self.problem}; {REPAIR_HINT}"


@dataclass
class StoreReport:
    """What :meth:`BakedDataset.verify` found: ``damage`` (empty when the store is intact), ``chunks``
    checked, ``checksums`` whether their contents were decoded too."""

    damage: list[Damage]
    chunks: int
    checksums: bool

    @property
    def ok(self) -> bool:
        return not self.damage

    @property
    def blocks(self) -> list[tuple[int, int]]:
        """Frame blocks ``(f0, f1)`` to re-bake: those with a damaged per-frame result or ``done`` chunk."""
        return sorted({(d.start, d.stop) for d in self.damage
                       if d.array in REBAKED and d.start is not None and d.stop is not None})

    @property
    def static(self) -> list[str]:
        """Creation-time arrays (``pose``, ``faces``, ``cluster``, ...) with a damaged chunk."""
        return sorted({d.array for d in self.damage if d.array not in REBAKED})

    def summary(self) -> str:
        """One line: how many damaged chunks, in which arrays."""
        names = sorted({d.array for d in self.damage})
        return f"{len(self.damage)} damaged chunk(s) in {', '.join(names)}" if names else "no damage"


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

    Every read through this class checks that the chunks it needs exist (a missing chunk of a done
    frame would otherwise read as zeros) and turns a chunk that fails to decode (crc32c mismatch,
    zstd error) into a one-line :class:`PrtError` naming the array and frames; :meth:`verify`
    checks the whole store.
    """

    def __init__(self, path: Path, validate: bool = True) -> None:
        import zarr

        self.path = Path(path)
        if not self.path.exists():
            raise MissingArtifact(f"dataset not found: {self.path}")
        try:
            self._group = zarr.open_group(str(self.path), mode="r")
        except Exception as exc:
            raise DamagedArtifact(f"{self.path}: not a zarr dataset ({type(exc).__name__})") from None
        self.attrs: dict[str, Any] = dict(self._group.attrs)
        self._arrays: dict[str, Any] = {}
        if not validate:
            return
        for name in ("pose", "visibility", "clip_id", "frame_index", "done", "cluster"):
            if name not in self._group:
                raise DamagedArtifact(f"{self.path}: dataset has no '{name}' array")
        for key in ("clip_names", "splits", "sh_order"):
            if key not in self.attrs:
                raise DamagedArtifact(f"{self.path}: dataset has no '{key}' attribute")

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
        """The zarr array ``name`` (for sliced reads; unchecked: prefer :meth:`rows`)."""
        a = self._arrays.get(name)
        if a is None:
            if name not in self._group:
                raise PrtError(f"{self.path}: dataset has no '{name}' array")
            a = self._arrays[name] = self._group[name]
        return a

    def __contains__(self, name: str) -> bool:
        return name in self._group

    # -- small arrays (cached) ----------------------------------------------------------------
    @cached_property
    def pose(self) -> np.ndarray:
        """``(F, A)`` float32 pose features."""
        return self._read("pose")

    @cached_property
    def clip_id(self) -> np.ndarray:
        """``(F,)`` int32."""
        return self._read("clip_id")

    @cached_property
    def frame_index(self) -> np.ndarray:
        """``(F,)`` int32."""
        return self._read("frame_index")

    @cached_property
    def faces(self) -> np.ndarray:
        """``(T, 3)`` int32."""
        return self._read("faces")

    @cached_property
    def cluster(self) -> np.ndarray:
        """``(V,)`` int32 local-frame cluster of each vertex."""
        return self._read("cluster")

    @cached_property
    def cluster_axis(self) -> np.ndarray:
        """``(Kc, 3)`` float32 rest-pose PCA axis of each cluster."""
        return self._read("cluster_axis")

    @cached_property
    def cluster_bone(self) -> np.ndarray:
        """``(Kc,)`` int32 dominant bone of each cluster."""
        return self._read("cluster_bone")

    @property
    def done(self) -> np.ndarray:
        """``(F,)`` bool completion mask (read fresh: a bake may be running)."""
        return self._read("done").astype(bool, copy=False)

    @property
    def complete(self) -> bool:
        return bool(self.done.all())

    # -- per-frame arrays (read on access) ----------------------------------------------------
    @property
    def visibility(self) -> np.ndarray:
        """``(F, V, C)`` float32 local-frame SH visibility."""
        return self._read("visibility")

    @property
    def transfer(self) -> np.ndarray | None:
        """``(F, V, C6)`` float32 world-frame diffuse transfer, or None if not baked."""
        return self._read("transfer") if "transfer" in self._group else None

    @property
    def positions(self) -> np.ndarray:
        """``(F, V, 3)`` float32 posed positions (world)."""
        return self._read("positions")

    @property
    def normals(self) -> np.ndarray:
        """``(F, V, 3)`` float32 posed unit normals (world)."""
        return self._read("normals")

    @property
    def frames(self) -> np.ndarray:
        """``(F, V, 3, 3)`` float32 vertex frames, rows ``(t, b, n)``."""
        return self._read("frames")

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
        """Per-frame arrays ``names`` at dataset ``rows`` (one orthogonal zarr read each).

        A missing chunk of a done frame, or a chunk that fails its checksum or does not decode, is a
        one-line :class:`PrtError` naming the array and frames (re-running ``prt bake`` repairs it).
        """
        rows = np.asarray(rows, dtype=np.int64)
        done = self.done if any(n in REBAKED for n in names) else None
        return {name: self._read(name, rows, done) for name in names}

    # -- integrity -----------------------------------------------------------------------------
    @property
    def format_version(self) -> int:
        """The store's layout (:data:`FORMAT_VERSION`; 1 = no checksums, fill-valued chunks not written)."""
        return int(self.attrs.get("format_version", 1))

    def _frame_axis(self, name: str) -> bool:
        return name in REBAKED or name in FRAME_STATIC

    def _chunk_range(self, name: str, i: int) -> tuple[int | None, int | None]:
        """Frames ``[f0, f1)`` of first-axis chunk ``i`` of a frame array, ``(None, None)`` otherwise."""
        if not self._frame_axis(name):
            return None, None
        a = self.array(name)
        c = int(a.chunks[0])
        return i * c, min(int(a.shape[0]), (i + 1) * c)

    def _required(self, name: str, i: int, done: np.ndarray | None) -> bool:
        """Whether first-axis chunk ``i`` of ``name`` must exist on disk."""
        if name == "done":
            return False  # a missing done chunk means "not baked yet"
        if name in PER_FRAME_RESULTS:
            f0, f1 = self._chunk_range(name, i)
            return done is not None and bool(done[f0:f1].any())
        return self.format_version >= 2  # creation-time arrays: every chunk is written since format 2

    def _chunks(self, name: str, first: Any = None) -> list[tuple[int, ...]]:
        """Chunk coordinates of ``name`` whose first index is in ``first`` (default: all)."""
        a = self.array(name)
        grid = [-(-int(s) // int(c)) for s, c in zip(a.shape, a.chunks, strict=True)]
        if not grid:
            return [()]
        firsts = range(grid[0]) if first is None else first
        rest = list(itertools.product(*(range(n) for n in grid[1:])))
        return [(int(i), *r) for i in firsts for r in rest]

    def _chunk_file(self, name: str, coords: tuple[int, ...]) -> Path:
        return self.path / name / self.array(name).metadata.encode_chunk_key(coords)

    def _selection(self, name: str, coords: tuple[int, ...]) -> tuple[slice, ...]:
        a = self.array(name)
        return tuple(slice(i * int(c), min(int(s), (i + 1) * int(c)))
                     for i, s, c in zip(coords, a.shape, a.chunks, strict=True))

    def _damage(self, name: str, coords: tuple[int, ...], problem: str) -> Damage:
        f0, f1 = self._chunk_range(name, coords[0]) if coords else (None, None)
        return Damage(name, f0, f1, problem)

    def _check_chunk(self, name: str, coords: tuple[int, ...]) -> Damage | None:
        """Decode one chunk; its :class:`Damage` when that fails."""
        try:
            self.array(name)[self._selection(name, coords)]
        except Exception as exc:
            return self._damage(name, coords, _unreadable(exc))
        return None

    def _read(self, name: str, rows: np.ndarray | None = None, done: np.ndarray | None = None) -> np.ndarray:
        """Array ``name`` (all of it, or first-axis ``rows``), its chunks checked; see :meth:`rows`."""
        a = self.array(name)
        frame = self._frame_axis(name)
        if frame:
            c = int(a.chunks[0])
            firsts = range(-(-int(a.shape[0]) // c)) if rows is None else np.unique(rows // c)
        else:
            firsts = None
        if name in PER_FRAME_RESULTS and done is None:
            done = self.done
        for coords in self._chunks(name, firsts):
            if coords and self._required(name, coords[0], done) and not self._chunk_file(name, coords).is_file():
                gap = self._damage(name, coords, "missing chunk (would read as zeros)")
                raise DamagedArtifact(gap.message(self.path))
        try:
            if rows is None or not frame:
                return np.asarray(a[...])
            return np.asarray(a.get_orthogonal_selection((rows,) + (slice(None),) * (len(a.shape) - 1)))
        except Exception as exc:
            for coords in self._chunks(name, firsts):
                bad = self._check_chunk(name, coords)
                if bad is not None:
                    raise DamagedArtifact(bad.message(self.path)) from None
            raise DamagedArtifact(f"{self.path}: array '{name}': {_unreadable(exc)}; {REPAIR_HINT}") from None

    def _done_checked(self) -> tuple[np.ndarray, list[Damage]]:
        """The done mask with damaged ``done`` chunks read as not done, and those chunks' damage."""
        a = self.array("done")
        try:
            return np.asarray(a[...], dtype=bool), []
        except Exception:
            pass
        done = np.zeros(a.shape, dtype=bool)
        damage = []
        for coords in self._chunks("done"):
            sel = self._selection("done", coords)
            try:
                done[sel] = np.asarray(a[sel], dtype=bool)
            except Exception as exc:
                damage.append(self._damage("done", coords, _unreadable(exc)))
        return done, damage

    def verify(self, checksums: bool = False) -> StoreReport:
        """Check the store: every chunk of a done block (and, format 2, of every creation-time array)
        exists on disk; with ``checksums`` also decode each existing chunk (crc32c, zstd).

        Without ``checksums`` this costs one ``stat`` per chunk; with them, one read of the store.
        A damaged ``done`` chunk counts as not done (and as damage: its block is re-baked).
        """
        done, damage = self._done_checked()
        n = len(self._chunks("done"))
        for name in sorted(self._group.array_keys()):
            if name == "done":
                continue
            present = []
            for coords in self._chunks(name):
                if name in PER_FRAME_RESULTS and not self._required(name, coords[0], done):
                    continue  # not baked yet: nothing to check
                n += 1
                if self._chunk_file(name, coords).is_file():
                    present.append(coords)
                elif self._required(name, coords[0] if coords else 0, done):
                    damage.append(self._damage(name, coords, "missing chunk (would read as zeros)"))
            if checksums:
                damage += self._decode_all(name, present)
        return StoreReport(damage=damage, chunks=n, checksums=checksums)

    def _decode_all(self, name: str, coords: list[tuple[int, ...]], batch_bytes: int = 64 << 20) -> list[Damage]:
        """Decode the chunks ``coords`` of ``name``: runs of consecutive frame chunks (up to ``batch_bytes``)
        in one read each, chunk by chunk only within a run that fails."""
        a = self.array(name)
        if not coords or len(a.shape) == 0 or any(c[1:] != (0,) * (len(c) - 1) for c in coords) \
                or any(int(s) != int(c) for s, c in zip(a.shape[1:], a.chunks[1:], strict=True)):
            return [d for d in (self._check_chunk(name, c) for c in coords) if d is not None]
        per = max(1, batch_bytes // max(1, int(np.prod(a.chunks)) * a.dtype.itemsize))
        c0 = int(a.chunks[0])
        runs: list[list[tuple[int, ...]]] = []
        for c in coords:
            if runs and c[0] == runs[-1][-1][0] + 1 and len(runs[-1]) < per:
                runs[-1].append(c)
            else:
                runs.append([c])
        damage = []
        for run in runs:
            try:
                a[run[0][0] * c0:min(int(a.shape[0]), (run[-1][0] + 1) * c0)]
            except Exception:
                damage += [d for d in (self._check_chunk(name, c) for c in run) if d is not None]
        return damage

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
            raise MissingArtifact(f"{self.path}: split '{split}' has no baked frames")
        clip_id = self.clip_id
        if max_frames is not None and len(idx) > max_frames:
            if contiguous:
                ids = clip_id[idx]
                per = max(2, -(-max_frames // len(np.unique(ids))))
                idx = np.sort(np.concatenate([idx[ids == c][:per] for c in np.unique(ids)]))
            else:
                idx = idx[evenly_spaced_indices(len(idx), max_frames)]
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

    def recorded_config(self) -> dict[str, Any]:
        """The run config recorded by the bake (:func:`recorded_config` of :attr:`attrs`; ``{}`` when absent)."""
        return recorded_config(self.attrs)

    def recorded_fps(self) -> float | None:
        """The frame rate the bake posed the clips at (:func:`recorded_fps` of :attr:`attrs`)."""
        return recorded_fps(self.attrs)

    def run_config(self) -> RunConfig | None:
        """The run config recorded by the bake, validated (:func:`recorded_run_config`; ``None`` when absent)."""
        return recorded_run_config(self.attrs, str(self.path))

    def clip_by_name(self, name: str, character: Character, fps: float | None = None) -> PlanClip:
        """A clip name as this dataset's run uses it - one of its clips (a split entry: e.g. a held-out frame range
        of a training clip) or a clip of ``character`` - as frames of the character's clips: the one rule,
        :func:`prt_torch.rig.load.clip_by_name`, with the recorded config's ``character`` section (none recorded:
        the character's clips only). ``fps``: the rate of a whole character clip (the bake's is
        :meth:`recorded_fps`)."""
        from prt_torch.rig.load import clip_by_name

        cfg = self.run_config()
        return clip_by_name(character, name, None if cfg is None else cfg.character, fps)

    def frame_poses(self, clips: list[str], frame_index: np.ndarray,
                    character: Character) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """``local (F, J, 4, 4)``, ``skin (F, J, 4, 4)`` float64 and the source clip of the dataset frames
        ``(clips[f], frame_index[f])`` (dataset clip names, indices into their source clips): each name resolved by
        the one rule (:meth:`clip_by_name`, so a held-out frame range of a training clip is that clip's frames) and
        posed as the bake posed it. A frame outside its clip's entry is a one-line error."""
        from prt_torch.shapes import check_shape

        fps = recorded_fps(self.attrs)
        check_shape(frame_index, "F", name="frame_poses: frame_index", dims={"F": len(clips)})
        local = np.empty((len(clips), character.num_joints, 4, 4), np.float64)
        skin = np.empty_like(local)
        sources = [""] * len(clips)
        for name in dict.fromkeys(clips):
            plan = self.clip_by_name(name, character, fps)
            sel = np.flatnonzero([c == name for c in clips])
            at = np.minimum(np.searchsorted(plan.frame_index, frame_index[sel]), len(plan.frame_index) - 1)
            if not np.all(plan.frame_index[at] == frame_index[sel]):
                raise PrtError(f"{self.path}: frames of clip {name!r} are not frames of its entry (clip "
                               f"{plan.source!r}, {len(plan.frame_index)} frames): the recorded config does not "
                               f"describe this dataset")
            poses = character.pose(plan.clip)
            local[sel], skin[sel] = poses.local[at], poses.skin[at]
            for i in sel:
                sources[i] = plan.source
        return local, skin, sources

    def row_poses(self, rows: np.ndarray, character: Character) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """:meth:`frame_poses` of the dataset rows ``rows (F,)``."""
        rows = np.asarray(rows, dtype=np.int64)
        names = self.clip_names
        return self.frame_poses([names[i] for i in self.clip_id[rows]], self.frame_index[rows].astype(np.int64),
                                character)

    def bake_config(self) -> BakeConfig:
        """The bake settings the store was baked with, validated (:func:`recorded_bake_config`)."""
        return recorded_bake_config(self.attrs, str(self.path))

    def character(self) -> Character:
        """The baked character of the run directory holding the dataset (hash-checked)."""
        from prt_torch.rundir import RunDir

        return RunDir(self.path).character(expect_hash=self.character_hash or None)

    def __repr__(self) -> str:
        return (f"BakedDataset({str(self.path)!r}, frames={self.n_frames}, vertices={self.n_vertices}, "
                f"order={self.sh_order}, done={int(self.done.sum())}/{self.n_frames})")


def _unreadable(exc: BaseException) -> str:
    """One line saying why a chunk did not decode."""
    msg = str(exc).splitlines()[0] if str(exc) else ""
    if "checksum" in msg.lower():
        return "chunk fails its crc32c checksum (corrupted)"
    return f"chunk does not decode ({type(exc).__name__}: {msg[:80]})"


def open_dataset(path: str | os.PathLike[str]) -> BakedDataset:
    """Open a baked dataset store for reading (a run directory holding one is accepted too)."""
    from prt_torch.rundir import RunDir

    p = Path(path)
    if p.is_dir() and not (p / "zarr.json").exists() and RunDir(p).dataset_path.is_dir():
        p = RunDir(p).dataset_path
    if not p.exists():
        raise MissingArtifact(f"dataset not found: {p}")
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
