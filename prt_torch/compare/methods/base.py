"""The registry of ``prt compare`` methods and what a method gets (:class:`CompareRun`, :class:`FrameSet`,
:class:`FrameBatch`, :class:`RadianceRequest`): the package :mod:`prt_torch.compare.methods` re-exports them and
imports the built-in methods, which import this module (never the package).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from prt_torch.errors import PrtError

if TYPE_CHECKING:
    from prt_torch.bake.store import BakedDataset
    from prt_torch.rig.character import Character
    from prt_torch.rundir import RunDir


@dataclass
class CompareRun:
    """What a method may use: the run, its dataset and character, the bake settings (``dataset.attrs["bake"]``),
    the model metadata and the export metadata (``None`` when the run is not exported)."""

    run: RunDir
    dataset: BakedDataset
    character: Character
    order: int
    bake: dict[str, Any]
    model_meta: dict[str, Any]
    export_meta: dict[str, Any] | None
    threads: int = 2

    @property
    def n_vertices(self) -> int:
        return int(self.character.num_vertices)


@dataclass
class FrameSet:
    """The posed frames compared: ``features (F, A)`` float32, ``positions (F, V, 3)`` float32 world,
    ``frames (F, V, 3, 3)`` float32 vertex frames (rows t, b, n), ``clip`` names per frame (a split's dataset clip
    names, e.g. a held-out frame range of a training clip), ``frame_index (F,)`` into the character clip each frame
    is cut from, ``rows (F,)`` the dataset rows (``-1`` for frames posed here) and, for dataset rows, the baked
    ``visibility``. A skinned character's frames also carry their pose, by the one clip-name rule
    (:func:`prt_torch.rig.load.clip_by_name`): ``local (F, J, 4, 4)`` float64 joint-local transforms, ``skin (F,
    J, 4, 4)`` float64 skinning matrices and ``sources`` (the character clip per frame); ``None`` for a deformable
    subject. A method poses from these, never by looking a clip name up in the character."""

    features: np.ndarray
    positions: np.ndarray
    frames: np.ndarray
    clips: list[str]
    frame_index: np.ndarray
    rows: np.ndarray
    baked_visibility: np.ndarray | None = None
    local: np.ndarray | None = None
    skin: np.ndarray | None = None
    sources: list[str] | None = None

    @property
    def n_frames(self) -> int:
        return int(self.features.shape[0])

    def batch(self, idx: np.ndarray | list[int] | int) -> FrameBatch:
        i = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        return FrameBatch(i, self.features[i], self.positions[i], self.frames[i])


@dataclass
class FrameBatch:
    """``B`` frames of a :class:`FrameSet`: ``index (B,)`` into it, ``features (B, A)``, ``positions (B, V, 3)``,
    ``frames (B, V, 3, 3)``."""

    index: np.ndarray
    features: np.ndarray
    positions: np.ndarray
    frames: np.ndarray


@dataclass
class RadianceRequest:
    """For radiance methods: the player's ``lighting`` (:class:`prt_torch.player.lighting.Lighting`), the
    ``rpos`` ``{name: RPO}`` and analytic ``brdfs`` ``{name: BRDF}``, and the camera ``eye (3,)``."""

    lighting: Any
    rpos: dict[str, Any]
    brdfs: dict[str, Any]
    eye: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Method(Protocol):
    """The protocol of a compared method (see the module docstring)."""

    name: ClassVar[str]
    output: ClassVar[str]
    runtime: str

    @classmethod
    def available(cls, run: CompareRun) -> bool: ...

    def prepare(self, run: CompareRun, frames: FrameSet) -> None: ...

    def visibility(self, batch: FrameBatch) -> np.ndarray: ...

    def bytes(self) -> int: ...


class MethodBase:
    """Convenience base class: visibility output, ``radiance`` not implemented, ``bytes() = 0``."""

    name: ClassVar[str] = ""
    output: ClassVar[str] = "visibility"
    runtime: str = ""
    #: run when no ``--methods`` are given (``False``: opt-in, e.g. heavy methods such as ``sg_vct``)
    default: ClassVar[bool] = True

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return True

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        pass

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        raise PrtError(f"method {self.name!r} does not produce visibility")

    def radiance(self, batch: FrameBatch, shading: RadianceRequest) -> dict[str, np.ndarray]:
        raise PrtError(f"method {self.name!r} does not produce radiance")

    def bytes(self) -> int:
        return 0

    def info(self) -> dict[str, Any]:
        """Extra JSON fields about the method (e.g. which graph file ran)."""
        return {}


#: name -> method class, in display order
METHODS: dict[str, type[MethodBase]] = {}


def register(cls: type[MethodBase]) -> type[MethodBase]:
    """Class decorator: add ``cls`` to :data:`METHODS` under ``cls.name`` (a duplicate name is an error)."""
    if not cls.name or not cls.name.replace("_", "").isalnum():
        raise PrtError(f"method name must be a non-empty identifier, got {cls.name!r}")
    if cls.name in METHODS and METHODS[cls.name] is not cls:
        raise PrtError(f"method {cls.name!r} is already registered")
    if cls.output not in ("visibility", "radiance"):
        raise PrtError(f"method {cls.name!r}: output must be 'visibility' or 'radiance', got {cls.output!r}")
    METHODS[cls.name] = cls
    return cls


def unregister(name: str) -> None:
    """Remove a method from the registry (tests)."""
    METHODS.pop(name, None)


def resolve(names: list[str] | None, run: CompareRun) -> list[str]:
    """The methods to run: ``names`` (each must be registered; a registered method the run cannot provide is an
    error) or every available default one (opt-in methods have ``default = False``); ``sh_truth`` is always first
    (every score is against it)."""
    if names:
        for n in names:
            if n not in METHODS:
                raise PrtError(f"unknown method {n!r}: expected one of {', '.join(METHODS)}")
        for n in names:
            if not METHODS[n].available(run):
                raise PrtError(f"method {n!r} is not available for {run.run.path}")
        chosen = list(dict.fromkeys(names))
    else:
        chosen = [n for n, cls in METHODS.items() if getattr(cls, "default", True) and cls.available(run)]
    return ["sh_truth"] + [n for n in chosen if n != "sh_truth"]
