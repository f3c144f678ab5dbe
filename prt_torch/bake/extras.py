"""What the bake computes besides visibility: the per-frame arrays method packages add (:data:`BAKE_EXTRAS`).

The core bake traces every frame (:func:`prt_torch.bake.trace.trace_frame`) into ``positions``, ``normals``,
``frames``, ``visibility`` and, with ``bake.transfer``, the diffuse ``transfer`` (bounces included) and, with
``bake.subsurface``, the ``subsurface`` exit transfer (:mod:`prt_torch.bake.subsurface`). A method package that
needs more from the same rays (seed 001's transfer matrices) provides a :class:`BakeExtra`: which arrays it adds
to a bake, and how it computes them from a traced frame. The runner creates the arrays with the store
(:func:`prt_torch.bake.runner.prepare`) and fills them frame by frame in the workers.

Both sides read the bake's parameters as the store records them (``attrs["bake"]``: the result-changing
``bake`` keys, e.g. ``transfer_matrix``, ``matrix_order``, ``matrix_bounces``, ``albedo``,
``transfer_order``), so a resumed bake computes exactly what the store was created for. An extra's array names
belong to the store's format (:data:`prt_torch.bake.store.PER_FRAME_RESULTS`: verified, repaired and read like
the core ones).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from prt_torch.errors import PrtError
from prt_torch.plugins import StageTable, hooks

if TYPE_CHECKING:
    import numpy as np

    from prt_torch.bake.trace import FrameResult, RaySet

#: per-frame array layout: name -> (shape of one frame, numpy dtype name)
ArraySpec = dict[str, tuple[tuple[int, ...], str]]


@dataclass(frozen=True)
class TracedFrame:
    """One traced frame of a bake, what a :class:`BakeExtra` computes from.

    Attributes:
        positions: ``(V, 3)`` posed vertex positions, world, as traced (float64 skinned, float32 from a cache).
        frames: ``(V, 3, 3)`` float32 vertex frames, rows ``(t, b, n)``.
        faces: ``(T, 3)`` triangles of the traced mesh.
        rays: the bake's :class:`~prt_torch.bake.trace.RaySet` (its ``below_horizon`` convention applies).
        result: :func:`~prt_torch.bake.trace.trace_frame`'s result; ``hits`` set when an extra of the bake
            :attr:`~BakeExtra.needs_hits`, ``transfer`` set with ``bake.transfer``.
        arrays: the frame's core arrays beyond the trace, from the same rays: ``subsurface (V, C6)`` float32
            when ``bake.subsurface`` is set.
    """

    positions: np.ndarray
    frames: np.ndarray
    faces: np.ndarray
    rays: RaySet
    result: FrameResult
    arrays: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class BakeExtra:
    """A method package's bake hook (:data:`BAKE_EXTRAS`).

    Attributes:
        arrays: ``arrays(params, n_vertices) -> {name: (per-frame shape, dtype)}``: the arrays it adds to a bake
            with the recorded parameters ``params`` (``attrs["bake"]``) of a ``n_vertices`` subject; ``{}`` when
            that bake does not ask for them.
        compute: ``compute(params, frame) -> {name: array}``: those arrays of one :class:`TracedFrame`, each of
            its declared per-frame shape.
        needs_hits: whether ``compute`` reads the frame's ray hits (the bake then traces with ``keep_hits``).
    """

    arrays: Callable[[Mapping[str, Any], int], ArraySpec]
    compute: Callable[[Mapping[str, Any], TracedFrame], dict[str, np.ndarray]]
    needs_hits: bool = False


#: what each method package adds to the bake: method package -> its :class:`BakeExtra` references (``()``: none)
BAKE_EXTRAS: StageTable = {
    "s001": ("prt_torch.s001.bake:TRANSFER_MATRICES",),
    "transfer": (),
    "local": (),
    "shexp": (),
    "vct": (),
    "heightfield": (),
    "cloth": (),
}


def bake_extras(params: Mapping[str, Any], n_vertices: int,
                core: Iterable[str] = ()) -> list[tuple[BakeExtra, ArraySpec]]:
    """The extras a bake with recorded parameters ``params`` computes, each with the arrays it adds (in
    :data:`BAKE_EXTRAS` order; extras adding nothing are left out). An array name outside the store's format,
    one of the ``core`` arrays, or added by two extras is a one-line :class:`PrtError`."""
    from prt_torch.bake.store import PER_FRAME_RESULTS

    out: list[tuple[BakeExtra, ArraySpec]] = []
    seen: set[str] = set(core)
    for extra in hooks(BAKE_EXTRAS):
        spec = extra.arrays(params, n_vertices)
        if not spec:
            continue
        for name in spec:
            if name not in PER_FRAME_RESULTS:
                raise PrtError(f"bake extra array {name!r} is not a per-frame result of the store format "
                               f"{list(PER_FRAME_RESULTS)}")
            if name in seen:
                raise PrtError(f"bake extra array {name!r} is already made by the bake or another extra")
            seen.add(name)
        out.append((extra, spec))
    return out
