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
    int8_weights: str | None = None,
    fp16_weights: str | None = None,
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
        int8_weights: a regular expression: MatMuls whose weight initializer's name matches it become int8
            MatMulNBits nodes (:func:`lower_int8_matmuls`); ``None``: none.
        fp16_weights: a regular expression: float32 initializers whose name matches it are stored in float16 and
            widened by a Cast (:func:`store_fp16`); ``None``: none.

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
        if int8_weights is not None:
            lower_int8_matmuls(model, int8_weights)
        if fp16_weights is not None:
            store_fp16(model, fp16_weights)
        set_metadata(model, metadata or {})
        onnx.checker.check_model(model, full_check=True)
        onnx.save(model, str(tmp))
    return path


#: accuracy level of the int8 MatMulNBits nodes: 4 = int8 compute (the input rounded to int8 per block: VNNI
#: dot products); 0 = float32 compute on dequantised weights (measured several times slower on the CPU provider)
INT8_ACCURACY_LEVEL = 4


def lower_int8_matmuls(model: Any, pattern: str) -> int:
    """Rewrite ``MatMul(A, W)`` nodes whose weight initializer ``W (K, N)`` (float32) has a name matching
    ``pattern`` into onnxruntime's ``com.microsoft.MatMulNBits`` with 8-bit weights: ``W`` is quantised by
    :func:`prt_torch.export.graphs.int8_quantize` (one float32 scale per output column and block of rows, no zero
    point: the default 128), stored as uint8 ``(N, n_blocks, block)``. Modifies ``model`` in place; returns the
    number of nodes rewritten."""
    import re

    from onnx import helper, numpy_helper

    from prt_torch.export.graphs import int8_quantize

    rx = re.compile(pattern)
    inits = {i.name: i for i in model.graph.initializer}
    users: dict[str, int] = {}
    for node in model.graph.node:
        for name in node.input:
            users[name] = users.get(name, 0) + 1
    count = 0
    nodes = []
    for node in model.graph.node:
        w_name = node.input[1] if node.op_type == "MatMul" and len(node.input) == 2 else ""
        init = inits.get(w_name)
        if init is None or not rx.search(w_name) or len(init.dims) != 2 or init.data_type != 1:
            nodes.append(node)
            continue
        w = numpy_helper.to_array(init)
        k, n = w.shape
        q, scales, block = int8_quantize(w)
        b_name, s_name = f"{w_name}.int8", f"{w_name}.scales"
        model.graph.initializer.append(numpy_helper.from_array((q.astype(np.int16) + 128).astype(np.uint8), b_name))
        model.graph.initializer.append(numpy_helper.from_array(scales.reshape(-1), s_name))
        nodes.append(helper.make_node("MatMulNBits", [node.input[0], b_name, s_name], list(node.output),
                                      name=(node.name or w_name) + "_int8", domain="com.microsoft", K=k, N=n, bits=8,
                                      block_size=block, accuracy_level=INT8_ACCURACY_LEVEL))
        users[w_name] -= 1
        count += 1
    del model.graph.node[:]
    model.graph.node.extend(nodes)
    unused = [i for i in model.graph.initializer if users.get(i.name, 0) == 0 and i.name in inits
              and rx.search(i.name)]
    for i in unused:
        model.graph.initializer.remove(i)
    if count and not any(o.domain == "com.microsoft" for o in model.opset_import):
        model.opset_import.append(helper.make_opsetid("com.microsoft", 1))
    return count


def store_fp16(model: Any, pattern: str) -> int:
    """Store the float32 initializers whose name matches ``pattern`` in float16: each becomes ``NAME.fp16`` plus a
    ``Cast`` to float32 named ``NAME`` at the head of the graph (onnxruntime folds it at load: half the file bytes,
    the same float32 kernels). The torch side must round those tensors through float16 for parity. Modifies
    ``model`` in place; returns the number of initializers converted."""
    import re

    from onnx import TensorProto, helper, numpy_helper

    rx = re.compile(pattern)
    casts, count = [], 0
    for init in list(model.graph.initializer):
        if init.data_type != TensorProto.FLOAT or not rx.search(init.name):
            continue
        w = numpy_helper.to_array(init)
        model.graph.initializer.remove(init)
        model.graph.initializer.append(numpy_helper.from_array(w.astype(np.float16), f"{init.name}.fp16"))
        casts.append(helper.make_node("Cast", [f"{init.name}.fp16"], [init.name], name=f"{init.name}_widen",
                                      to=TensorProto.FLOAT))
        count += 1
    if casts:
        nodes = [*casts, *model.graph.node]
        del model.graph.node[:]
        model.graph.node.extend(nodes)
    return count


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


def weight_macs(path: str | os.PathLike[str]) -> int:
    """Multiply-adds per sample of the graph's weight GEMMs: ``K * N`` of every MatMul / Gemm whose second input is an
    initializer, ``K * N`` of every MatMulNBits, and the element count of every initializer an Einsum reads (the
    per-cluster MLP layers) - the FLOPs a batch row must run against the model's weights."""
    import onnx

    model = onnx.load(str(path))
    inits = {i.name: tuple(i.dims) for i in model.graph.initializer}
    total = 0
    for node in model.graph.node:
        if node.op_type in ("MatMul", "Gemm") and len(node.input) > 1 and node.input[1] in inits:
            total += int(np.prod(inits[node.input[1]], dtype=np.int64))
        elif node.op_type == "MatMulNBits":
            attrs = {a.name: a.i for a in node.attribute}
            total += int(attrs.get("K", 0)) * int(attrs.get("N", 0))
        elif node.op_type == "Einsum":
            total += sum(int(np.prod(inits[n], dtype=np.int64)) for n in node.input if n in inits)
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
