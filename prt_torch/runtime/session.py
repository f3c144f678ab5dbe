"""ONNX Runtime sessions for the run-time path (numpy + onnxruntime only; never torch).

:class:`OrtGraph` wraps an ``onnxruntime.InferenceSession`` with

* thread settings for a small CPU (``intra_op_num_threads``, sequential execution, all graph
  optimisations);
* input validation against the graph's declared shapes (symbolic axes such as ``B`` accept any
  size but must agree between inputs), float32 conversion and a NaN/Inf check, each failure a
  one-line :class:`PrtError`;
* a fast path (:meth:`OrtGraph.run_unchecked`) for the per-frame loop once inputs are known-good;
* ``device="cuda"``: onnxruntime's CUDA execution provider (the ``onnxruntime-gpu`` package, extra ``gpu``), with
  the CPU provider behind it for any node CUDA lacks.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape

#: onnx tensor type string -> numpy dtype
_ORT_TYPES = {"tensor(float)": np.float32, "tensor(double)": np.float64, "tensor(int64)": np.int64,
              "tensor(int32)": np.int32, "tensor(bool)": np.bool_}


#: caps every session's intra-op threads (a small machine, or the suite's 1-thread configuration)
THREADS_ENV = "PRT_ORT_THREADS"


def session_threads(threads: int) -> int:
    """``threads``, capped by ``$PRT_ORT_THREADS`` when it is set (a positive integer; else a one-line error)."""
    cap = os.environ.get(THREADS_ENV, "").strip()
    if not cap:
        return max(1, int(threads))
    if not cap.isdigit() or int(cap) < 1:
        raise PrtError(f"{THREADS_ENV}={cap!r}: expected a positive integer")
    return max(1, min(int(threads), int(cap)))


def session_options(threads: int = 2, spinning: bool = False):  # -> onnxruntime.SessionOptions
    """Session options tuned for the per-frame loop on a few CPU cores (``threads`` capped by
    :func:`session_threads`).

    ``spinning=False`` stops idle intra-op threads from busy-waiting: on 2 cores the numpy half of
    each frame (posing) and other processes then get the CPU (measured several times faster under load).
    """
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = session_threads(threads)
    so.inter_op_num_threads = 1
    so.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    return so


#: devices of :class:`OrtGraph`
DEVICES = ("cpu", "cuda")


def cuda_available() -> bool:
    """Whether onnxruntime offers its CUDA execution provider here (``onnxruntime-gpu`` installed); a GPU is
    needed too for a session to start on it (:func:`providers_for` checks)."""
    import onnxruntime as ort

    return "CUDAExecutionProvider" in ort.get_available_providers()


def providers_for(device: str) -> list[str]:
    """onnxruntime providers for ``device`` (``"cpu"`` or ``"cuda"``); one-line :class:`PrtError` when CUDA is asked
    for and onnxruntime cannot offer it."""
    if device not in DEVICES:
        raise PrtError(f"unknown device {device!r}: expected one of {list(DEVICES)}")
    if device == "cpu":
        return ["CPUExecutionProvider"]
    if not cuda_available():
        raise PrtError("device 'cuda' needs onnxruntime-gpu (pip install 'prt-torch[gpu]') and a CUDA GPU; "
                       "this onnxruntime offers only the CPU")
    return ["CUDAExecutionProvider", "CPUExecutionProvider"]


class OrtGraph:
    """One ONNX graph loaded into onnxruntime (CPU, or CUDA with ``device="cuda"``), with checked and unchecked
    run methods.

    Attributes:
        path: the ``.onnx`` file.
        metadata: its ``metadata_props`` (str -> str).
        inputs: ``{name: shape}`` with ``str`` for symbolic axes and ``int`` for fixed ones.
        outputs: output names in graph order.
    """

    def __init__(self, path: str | os.PathLike[str], threads: int = 2, spinning: bool = False,
                 device: str = "cpu") -> None:
        import onnxruntime as ort

        self.path = Path(path)
        self.threads = session_threads(threads)  # onnxruntime intra-op threads of this session
        if not self.path.is_file():
            raise PrtError(f"ONNX file not found: {self.path}")
        providers = providers_for(device)
        self.device = device
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=session_options(threads, spinning),
                                                providers=providers)
        except Exception as exc:  # onnxruntime raises its own exception types
            raise PrtError(f"{self.path}: onnxruntime cannot load it ({str(exc).splitlines()[0][:200]})") from None
        if device == "cuda" and "CUDAExecutionProvider" not in self.session.get_providers():
            raise PrtError(f"{self.path}: onnxruntime could not start its CUDA provider (no usable GPU?)")
        meta = self.session.get_modelmeta()
        self.metadata: dict[str, str] = dict(meta.custom_metadata_map)
        self.inputs: dict[str, tuple[int | str, ...]] = {
            i.name: tuple(d if isinstance(d, int) else str(d) for d in i.shape) for i in self.session.get_inputs()}
        self.input_types = {i.name: _ORT_TYPES.get(i.type, np.float32) for i in self.session.get_inputs()}
        self.outputs: list[str] = [o.name for o in self.session.get_outputs()]

    def check_inputs(self, feeds: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Validate and convert ``feeds``; returns contiguous arrays of the graph's dtypes.

        Raises :class:`PrtError` for a missing/unknown input, a wrong rank or size, symbolic axes
        that disagree between inputs, or non-finite values.
        """
        missing = [n for n in self.inputs if n not in feeds]
        if missing:
            raise PrtError(f"{self.path.name}: missing input(s) {', '.join(missing)}")
        unknown = [n for n in feeds if n not in self.inputs]
        if unknown:
            raise PrtError(f"{self.path.name}: unknown input(s) {', '.join(unknown)}; expected {list(self.inputs)}")
        symbols: dict[str, int] = {}
        out: dict[str, np.ndarray] = {}
        for name, shape in self.inputs.items():
            a = np.asarray(feeds[name])
            check_shape(a, shape, name=f"{self.path.name}: input '{name}'", dims=symbols)
            dtype = self.input_types[name]
            a = np.ascontiguousarray(a, dtype=dtype)
            if np.issubdtype(dtype, np.floating) and not np.isfinite(a).all():
                raise PrtError(f"{self.path.name}: input '{name}' contains NaN or Inf")
            out[name] = a
        return out

    def run(self, feeds: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Checked run: validates ``feeds`` and returns ``{output name: array}``."""
        checked = self.check_inputs(feeds)
        return dict(zip(self.outputs, self.session.run(self.outputs, checked), strict=True))

    def run_unchecked(self, feeds: Mapping[str, np.ndarray]) -> list[np.ndarray]:
        """The per-frame fast path: float32 contiguous inputs assumed; outputs in graph order."""
        return self.session.run(self.outputs, feeds)
