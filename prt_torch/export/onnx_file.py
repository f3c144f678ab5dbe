"""Writing, checking and inspecting ONNX files (generic machinery, any ``nn.Module``).

:func:`export_onnx` traces a module to an ONNX graph (opset >= 17, named inputs/outputs, dynamic
axes), runs ``onnx.checker``, stamps string metadata properties into the model and writes it
atomically. :func:`read_metadata` and :func:`initializer_bytes` read a file back with ``onnx``
alone (no torch), so the run-time player can use them.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.io import atomic_path

if TYPE_CHECKING:
    import torch

#: lowest opset we write (the issue asks for >= 17)
MIN_OPSET = 17
DEFAULT_OPSET = 17


def export_onnx(
    module: torch.nn.Module,
    args: Sequence[torch.Tensor],
    path: str | os.PathLike[str],
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_axes: Mapping[str, Mapping[int, str]] | None = None,
    metadata: Mapping[str, Any] | None = None,
    opset: int = DEFAULT_OPSET,
    exporter: str = "torchscript",
) -> Path:
    """Export ``module(*args)`` to ``path`` (atomically) and check the result.

    Args:
        module: the torch module; it is put in ``eval()`` mode.
        args: example inputs, one tensor per entry of ``input_names``.
        path: destination ``.onnx`` file.
        input_names, output_names: graph input / output names.
        dynamic_axes: ``{name: {axis: symbol}}`` for inputs and outputs, e.g. ``{"pose": {0: "B"}}``.
        metadata: string-valued metadata properties (values are converted with ``str``).
        opset: ONNX opset (>= 17).
        exporter: ``"torchscript"`` (``torch.onnx.export(dynamo=False)``, fast) or ``"dynamo"``.

    Returns:
        ``Path(path)``.
    """
    import onnx
    import torch

    if opset < MIN_OPSET:
        raise PrtError(f"ONNX opset {opset} is too old: need >= {MIN_OPSET}")
    if len(args) != len(input_names):
        raise PrtError(f"export: {len(args)} example inputs but {len(input_names)} input names")
    if exporter not in ("torchscript", "dynamo"):
        raise PrtError(f"unknown ONNX exporter {exporter!r}: expected 'torchscript' or 'dynamo'")
    path = Path(path)
    module = module.eval()
    dynamic_axes = {k: dict(v) for k, v in (dynamic_axes or {}).items()}
    with atomic_path(path) as tmp, torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if exporter == "torchscript":
            torch.onnx.export(module, tuple(args), str(tmp), input_names=list(input_names),
                              output_names=list(output_names), dynamic_axes=dynamic_axes,
                              opset_version=opset, dynamo=False, do_constant_folding=True)
        else:
            dims: dict[str, Any] = {}
            shapes: list[Any] = []  # positional, matching args (argument names need not equal input names)
            for name in input_names:
                axes = dynamic_axes.get(name)
                shapes.append({ax: dims.setdefault(sym, torch.export.Dim(sym)) for ax, sym in axes.items()}
                              if axes else None)
            prog = torch.onnx.export(module, tuple(args), input_names=list(input_names),
                                     output_names=list(output_names), dynamic_shapes=tuple(shapes),
                                     opset_version=opset, dynamo=True, verbose=False)
            prog.save(str(tmp))
        model = onnx.load(str(tmp))
        set_metadata(model, metadata or {})
        onnx.checker.check_model(model, full_check=True)
        onnx.save(model, str(tmp))
    return path


def set_metadata(model: Any, metadata: Mapping[str, Any]) -> None:
    """Replace/add ``metadata_props`` of an ``onnx.ModelProto`` (values stringified)."""
    existing = {p.key: p for p in model.metadata_props}
    for key, value in metadata.items():
        if key in existing:
            existing[key].value = str(value)
        else:
            prop = model.metadata_props.add()
            prop.key, prop.value = str(key), str(value)


def read_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``metadata_props`` of an ONNX file as a dict (reads with ``onnx``; no torch)."""
    import onnx

    path = Path(path)
    if not path.is_file():
        raise PrtError(f"ONNX file not found: {path}")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises DecodeError & co.
        raise PrtError(f"{path}: not a readable ONNX model ({type(exc).__name__})") from None
    return {p.key: p.value for p in model.metadata_props}


def initializer_bytes(path: str | os.PathLike[str]) -> int:
    """Total size in bytes of the graph's initializers (the model's weights and constants)."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(path))
    total = 0
    for init in model.graph.initializer:
        total += numpy_helper.to_array(init).nbytes
    for node in model.graph.node:  # constants folded into Constant nodes count as weights too
        if node.op_type == "Constant":
            for attr in node.attribute:
                if attr.type == onnx.AttributeProto.TENSOR:
                    total += int(np.prod(attr.t.dims, dtype=np.int64)) * _itemsize(attr.t.data_type)
    return total


def _itemsize(onnx_dtype: int) -> int:
    from onnx import helper

    return np.dtype(helper.tensor_dtype_to_np_dtype(onnx_dtype)).itemsize


def opset_of(path: str | os.PathLike[str]) -> int:
    """The default-domain opset version of an ONNX file."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    for imp in model.opset_import:
        if imp.domain in ("", "ai.onnx"):
            return int(imp.version)
    raise PrtError(f"{path}: no default-domain opset import")
