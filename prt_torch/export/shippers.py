"""The export stage's table: what ``prt export`` ships besides the visibility, shading and fused graphs.

``prt export`` (:func:`prt_torch.export.run.export_run`) asks every :class:`Shipper` of :data:`SHIPPERS`, in the
table's order, twice:

1. before anything is exported, :attr:`Shipper.plan` gives its :class:`Shipment`: the files it will write (export
   outputs: refreshed together, their sha256 in ``export.json`` ``file_sha256``) and its part of the export stage
   key (merged into the key's top level; a part a run does not need is ``{}``, so the keys of runs exported before
   the method existed stay valid);
2. after the core graphs are written and checked, :attr:`Shipper.ship` writes its files from the
   :class:`ShipInputs` and returns its ``export.json`` entry (key :attr:`Shipper.name`), or ``None`` when the run
   has nothing of it (the files an earlier export left are then removed by the shipper).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.plugins import StageTable, hooks
from prt_torch.rundir import RunDir

#: the shippers of each method package (:class:`Shipper` references); they ship in this table's order (the order
#: of their console lines): sphere blockers + SHEXP graph, learned transfer, the deformable graphs, the local network
SHIPPERS: StageTable = {
    "shexp": ("prt_torch.shexp.graph:SHIPPER",),
    "transfer": ("prt_torch.transfer.graph:SHIPPER",),
    "cloth": ("prt_torch.cloth.export:SHIPPER",),
    "local": ("prt_torch.local.graph:SHIPPER",),
    "s001": (),
    "vct": (),
    "heightfield": (),
}


@dataclass(frozen=True)
class ExportRequest:
    """What a shipper's plan sees: the run and the export's settings, before anything is exported.

    Attributes:
        run: the run directory.
        precision: the requested weight precision (``fp32``, ``fp16``, ``int8``).
        opset: the ONNX opset.
        exporter: ``"torchscript"`` or ``"dynamo"``.
        deform: the caller's deformable spec (``export_run(deform=)``; ``None``: the shipper builds it from the run).
        deformable: whether the run is deformable (``deform`` given, or the dataset is a deformable one).
        per_cluster: whether the exported model has per-cluster output bases (the compiled frame path's decode).
    """

    run: RunDir
    precision: str
    opset: int
    exporter: str
    deform: Any = None
    deformable: bool = False
    per_cluster: bool = False


@dataclass(frozen=True)
class Shipment:
    """A shipper's plan for one run.

    Attributes:
        files: the files it writes (export outputs; empty: it ships nothing for this run).
        key: its part of the export stage key (``{}``: none).
        state: what its :attr:`Shipper.ship` needs from the plan (e.g. the deformable spec).
    """

    files: tuple[Path, ...] = ()
    key: Mapping[str, Any] = field(default_factory=dict)
    state: Any = None


@dataclass(frozen=True)
class ShipInputs:
    """The core export's products the shippers ship from.

    Attributes:
        run: the run directory.
        character: the run's :class:`~prt_torch.rig.character.Character`.
        order: SH order of the model.
        opset: the ONNX opset.
        exporter: ``"torchscript"`` or ``"dynamo"``.
        precision: the exported precision (the model's: ``fp32`` for a model without per-cluster bases).
        rtol: the parity tolerance of that precision.
        lowered: the ``export_onnx`` keyword arguments of that precision.
        base_meta: the ONNX metadata every graph of the export carries.
        held: held-out ``pose (F, A)``, ``frames (F, V, 3, 3)``, ``positions (F, V, 3)``, ``rows (F,)``.
        vis_graph: the exported :class:`~prt_torch.export.graphs.VisibilityGraph`.
        fused_graph: the exported :class:`~prt_torch.export.graphs.FusedGraph`.
        fused_inputs: its parity inputs (``pose`` and the shading inputs, vertex axes in its order).
        console: where the shippers print their parity lines (``None``: quiet).
    """

    run: RunDir
    character: Any
    order: int
    opset: int
    exporter: str
    precision: str
    rtol: float
    lowered: Mapping[str, str | None]
    base_meta: dict[str, Any]
    held: dict[str, np.ndarray]
    vis_graph: Any
    fused_graph: Any
    fused_inputs: dict[str, np.ndarray]
    console: Any = None

    def log(self, line: str) -> None:
        """Print ``line`` on the console (nothing without one)."""
        if self.console is not None:
            self.console.print(line)


@dataclass(frozen=True)
class InputGraph:
    """A visibility graph behind another input (e.g. positions -> dihedral angles -> the model).

    Attributes:
        module: the torch module, ``*inputs -> visibility (B, V, C)``.
        names: its input names.
        example: example inputs (float32 tensors, batch 1), one per name.
    """

    module: Any
    names: tuple[str, ...]
    example: tuple[Any, ...]


@dataclass(frozen=True)
class Shipper:
    """One method's part of ``prt export``.

    Attributes:
        name: its ``export.json`` key.
        plan: ``plan(request: ExportRequest) -> Shipment``.
        ship: ``ship(shipment: Shipment, inputs: ShipInputs) -> export.json entry | None``.
        input_graph: for a shipper whose graph feeds the visibility model another input: ``input_graph(run,
            vis_graph, character) -> InputGraph`` builds that graph around another visibility graph (``prt
            compare`` runs every learned kind that way); ``None`` for the others.
    """

    name: str
    plan: Callable[[ExportRequest], Shipment]
    ship: Callable[[Shipment, ShipInputs], dict[str, Any] | None]
    input_graph: Callable[[RunDir, Any, Any], InputGraph] | None = None


def shippers() -> list[Shipper]:
    """Every :class:`Shipper` of :data:`SHIPPERS`, loaded, in the table's order (the order they ship in)."""
    return hooks(SHIPPERS)


def shipper_of(name: str) -> Shipper:
    """The shipper of ``export.json``'s ``name`` entry (one-line PrtError when none ships it)."""
    for s in shippers():
        if s.name == name:
            return s
    raise PrtError(f"no export shipper writes the export metadata's {name!r} entry")


def merge_parts(core: Mapping[str, Any], parts: list[Mapping[str, Any]], what: str) -> dict[str, Any]:
    """``core`` with every shipper's part merged in at the top level (the stage key, ``export.json``); a name two
    of them give is a one-line PrtError naming ``what`` (a shipper may not shadow the core's or another's)."""
    out = dict(core)
    for part in parts:
        clash = sorted(set(out) & set(part))
        if clash:
            raise PrtError(f"{what}: export shippers give {clash} twice")
        out.update(part)
    return out
