"""Resource bounds: every size a config or a command line can ask for, in one place.

The machine the project is sized for has 2 CPU cores and 24 GiB of memory. Every number a user
can type that turns into an allocation, a loop count or an output size is checked against a bound
here BEFORE anything is allocated or written; a request over a bound is a one-line
:class:`~prt_torch.errors.PrtError` (configs: a pydantic error naming the key) that says the bound
and, for memory, the estimate. The bounds are generous for real work (the shipped configs use a
small fraction of each) and refuse only what cannot finish or would exhaust memory.

This module is bottom-layer (rank 0) and imports neither numpy nor torch.
"""

from __future__ import annotations

import math
import re

from prt_torch.errors import PrtError

# -- the machine ---------------------------------------------------------------------------------------------------

#: memory of the target machine; no single request may plan to use more than a fraction of it
MACHINE_MEMORY_BYTES = 24 * 2**30
#: in-RAM arrays of one bake task (one worker process; 2 workers + the main process must fit)
MAX_TASK_BYTES = 6 * 2**30
#: any other single in-RAM allocation sized from user input (images, batches, benchmark arrays)
MAX_ARRAY_BYTES = 8 * 2**30

# -- config files --------------------------------------------------------------------------------------------------

#: size of a YAML config file (the shipped ones are ~2 KB)
MAX_CONFIG_BYTES = 1 * 2**20
#: nesting depth of a YAML config (mappings/sequences; the schema needs 4)
MAX_CONFIG_DEPTH = 32
#: YAML nodes of a config, aliases expanded (bounds "billion laughs" documents)
MAX_CONFIG_NODES = 100_000
#: length of a run name (it becomes a directory name)
MAX_NAME_LENGTH = 128
#: length of a path or other free string in a config
MAX_STRING_LENGTH = 4096
#: entries of a list in a config (clips, alphas, neuron counts)
MAX_LIST_LENGTH = 256

# -- rates, frames, seeds ------------------------------------------------------------------------------------------

#: frames per second of a clip (configs' ``character.fps``, ``prt play/info --fps``)
MAX_FPS = 1000.0
#: frames of one bake, evaluation, comparison or playback
MAX_FRAMES = 1_000_000
#: a frame index in a clip range (``frames: "a:b"``), either sign
MAX_FRAME_INDEX = 10_000_000
#: seconds in a clip range (``times: "t0:t1"``)
MAX_CLIP_SECONDS = 1_000_000.0
#: random training poses of a bake (``character.random_poses``)
MAX_RANDOM_POSES = 200_000
#: random seeds are in ``0..MAX_SEED`` (numpy's legacy generators need < 2**32)
MAX_SEED = 2**32 - 1

# -- geometry and rays ---------------------------------------------------------------------------------------------

#: the built-in humanoid's ``density`` (``rig.builtin.make_character`` accepts this range)
MIN_DENSITY = 0.02
MAX_DENSITY = 16.0
#: vertices of the built-in humanoid per unit density (11,730 at 1.0; the estimate rounds up)
BUILTIN_VERTICES_PER_DENSITY = 12_500
#: vertices of a character or benchmark mesh
MAX_VERTICES = 2_000_000
#: character height a glTF file is rescaled to (``character.height``)
MAX_HEIGHT = 1.0e4
#: the largest glTF rest vertex coordinate (file units, z-up world): float32 positions (~7 significant digits)
#: this far from the origin are steps of 1 unit, too coarse for any character's shape
MAX_COORDINATE = 1.0e7
#: the farthest a glTF rest vertex may lie from the mesh's per-axis median, in multiples of the median vertex
#: distance from it (the robust extent; ~2 for the shared characters): one stray vertex would otherwise become
#: the character's size (``character.height`` would shrink the rest to a point) and its bounds
MAX_VERTEX_SPREAD = 100.0
#: hemisphere rays per vertex (bake ``n_rays``, compare ``--reference-rays``, bench ``--rays``)
MAX_RAYS = 65_536
#: rays per Embree call (``bake.vertex_chunk_rays``; ~100 bytes of buffers per ray)
MAX_CHUNK_RAYS = 1 << 24
#: frames per bake task (``bake.frames_per_task``; also bounded by :data:`MAX_TASK_BYTES`)
MAX_FRAMES_PER_TASK = 4096
#: local clusters of a bake (``bake.max_clusters``)
MAX_CLUSTERS = 4096

# -- processes and threads -----------------------------------------------------------------------------------------

#: worker processes of a local bake pool (more than the cores only adds memory)
MAX_WORKERS = 256
#: threads of onnxruntime / torch
MAX_THREADS = 256

# -- fitting and export --------------------------------------------------------------------------------------------

#: L-BFGS iterations (``train.max_iter``, ``train.cv_iter``, ``prt bench fit --max-iter``)
MAX_ITERATIONS = 1_000_000
#: cross-validation folds
MAX_FOLDS = 64
#: hidden neurons of one MLP
MAX_NEURONS = 4096
#: a ridge / MLP regularisation weight
MAX_ALPHA = 1.0e12
#: L-BFGS history
MAX_HISTORY = 1000
#: BRDF terms ``k`` of an RPO / shading graph (``prt export --terms``, ``prt bench shade --k``)
MAX_TERMS = 64
#: ONNX opsets the exporters write (torch's TorchScript exporter stops at 20)
MIN_OPSET = 17
MAX_OPSET = 20

# -- images and playback -------------------------------------------------------------------------------------------

#: height and width of a rendered image or window (``--size HxW``)
MAX_IMAGE_SIDE = 8192
#: characters per batched call (``prt bench play --batch``)
MAX_BATCH = 4096
#: repetitions of a benchmark measurement
MAX_REPEATS = 10_000

#: a Dask scheduler address: ``tcp://HOST:PORT`` (or ``tls://``), HOST a name, IPv4 or [IPv6]
SCHEDULER_PATTERN = r"^(tcp|tls)://([A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?|\[[0-9A-Fa-f:.]+\]):([0-9]{1,5})$"


def human_bytes(n: float) -> str:
    """``12345678`` -> ``'11.8 MiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover


def check_scheduler(address: str) -> str:
    """``address`` if it is ``tcp://HOST:PORT`` (port 1..65535); else a :class:`ValueError` naming the form."""
    m = re.match(SCHEDULER_PATTERN, address)
    if m is None or not 1 <= int(m.group(4)) <= 65535:
        raise ValueError(f"bad scheduler address {address[:200]!r}: expected tcp://HOST:PORT (port 1..65535)")
    return address


def check_int(value: int, name: str, lo: int, hi: int) -> int:
    """``value`` if ``lo <= value <= hi``; else a one-line :class:`PrtError` naming ``name`` and the range."""
    if not lo <= value <= hi:
        raise PrtError(f"{name} must be in {lo}..{hi}, got {value}")
    return value


def check_float(value: float, name: str, lo: float, hi: float, lo_open: bool = False) -> float:
    """``value`` if finite and in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``); else a one-line :class:`PrtError`."""
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        raise PrtError(f"{name} must be {'>' if lo_open else '>='} {lo:g} and <= {hi:g} (finite), got {value}")
    return value


def parse_size(text: str, name: str = "--size") -> tuple[int, int]:
    """``"HxW"`` -> ``(h, w)``, each in ``1..MAX_IMAGE_SIDE``, within :data:`MAX_ARRAY_BYTES` as RGBA float32."""
    parts = text.strip().lower().split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        h, w = (int(p) for p in parts)
    except ValueError:
        raise PrtError(f"bad {name} {text[:64]!r}: expected HxW, e.g. 480x640") from None
    if not (1 <= h <= MAX_IMAGE_SIDE and 1 <= w <= MAX_IMAGE_SIDE):
        raise PrtError(f"bad {name} {text[:64]!r}: height and width must be in 1..{MAX_IMAGE_SIDE}")
    return h, w


def bake_task_bytes(frames: int, vertices: int, order: int, transfer_order: int | None = None,
                    matrix_order: int | None = None, n_rays: int = 0, subsurface: bool = False) -> int:
    """Estimated in-RAM bytes of one bake task of ``frames`` frames of ``vertices`` vertices.

    Per vertex and frame: posed positions and normals in float64 (48 B) and their float32 copies (24 B), the
    vertex frame (9 float32), the visibility (``order**2`` float32) and, with transfer, ``transfer_order**2``
    float32. (On disk the dataset stores ``frames x vertices x (C + 9 + 6) x 4`` bytes over the whole bake;
    only one task's block is in memory at a time.) With transfer matrices (``matrix_order``) or ``subsurface``:
    ``matrix_order**4`` (and ``transfer_order**2``) float32 more per vertex and frame, plus one frame's ray hits
    (``n_rays`` x 13 bytes per vertex: triangle, barycentrics, occlusion).
    """
    c6 = transfer_order * transfer_order if transfer_order else 0
    per = 48 + 24 + 4 * (9 + order * order + c6)
    per += 4 * (matrix_order**4 if matrix_order else 0) + (4 * c6 if subsurface else 0)
    hits = 13 * int(n_rays) * int(vertices) if (matrix_order or subsurface) else 0
    return int(frames) * int(vertices) * per + hits


def check_bake_task_memory(frames: int, vertices: int, order: int, transfer_order: int | None = None,
                           what: str = "bake.frames_per_task", matrix_order: int | None = None, n_rays: int = 0,
                           subsurface: bool = False) -> int:
    """Raise a one-line :class:`PrtError` with the estimate when a bake task exceeds :data:`MAX_TASK_BYTES`."""
    need = bake_task_bytes(frames, vertices, order, transfer_order, matrix_order, n_rays, subsurface)
    if need > MAX_TASK_BYTES:
        raise PrtError(f"{what}: one bake task of {frames} frames x {vertices:,} vertices needs about "
                       f"{human_bytes(need)} of memory, over the {human_bytes(MAX_TASK_BYTES)} bound; "
                       f"use fewer frames per task or vertices")
    return need


def check_array_memory(n_bytes: float, what: str) -> float:
    """Raise a one-line :class:`PrtError` with the estimate when ``n_bytes`` exceeds :data:`MAX_ARRAY_BYTES`."""
    if not n_bytes <= MAX_ARRAY_BYTES:
        raise PrtError(f"{what} needs about {human_bytes(n_bytes)} of memory, over the "
                       f"{human_bytes(MAX_ARRAY_BYTES)} bound")
    return n_bytes
