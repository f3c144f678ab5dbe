"""The bake job: plan the frames, create (or resume) the store, run blocks of frames in parallel.

``bake(cfg)`` is resumable and deterministic: the store is chunked by blocks of
``frames_per_task`` frames, each block is one task (a local process, or a Dask task with
``scheduler="tcp://HOST:PORT"``), and a block's ``done`` entries are written after its data.
Re-running skips finished blocks; a run killed at any moment (even SIGKILL) loses only the
blocks in flight, and the resumed result is bitwise equal to an uninterrupted bake, whatever the
number of workers or the backend (all randomness comes from the config's seeds, and BLAS runs
single-threaded inside a task).

Failure model: a bake holds the run directory's lock (:meth:`RunDir.lock`) for its whole run, so a
second bake of the same run directory stops at once with one line naming the holder; the store is
created in a temporary directory and renamed into place without replacing anything; on resume the
store is verified (missing chunks of done blocks, crc32c/decode failures) and the damaged blocks'
``done`` entries are cleared, so they are baked again (damaged creation-time arrays are rewritten
from the plan). Local pool workers die with their parent (``PR_SET_PDEATHSIG`` on Linux, and a
watchdog thread polling the parent pid everywhere), so a killed bake leaves no process writing. A Dask
worker that dies mid-bake (killed, out of memory) loses only its tasks: the scheduler runs them, and any finished
result it held, again on the other workers (or the one its nanny restarts), and the bake ends with no ``*.partial``
chunk write of the dead worker left in the store (tests/bake/test_dask_faults.py).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.bake.deformable import clusters as deformable_clusters
from prt_torch.bake.deformable import frame_operator, is_deformable, posed_frames, source_of
from prt_torch.bake.embree import ray_offset, require_embreex
from prt_torch.bake.extras import ArraySpec, BakeExtra, TracedFrame, bake_extras
from prt_torch.bake.peaks import record_frame
from prt_torch.bake.plan import BakePlan, make_plan
from prt_torch.bake.store import (
    FORMAT_VERSION,
    PER_FRAME_RESULTS,
    BakedDataset,
    StoreReport,
    below_horizon_of,
    check_compatible,
    conventions,
    create_store,
    library_versions,
    open_for_writing,
    remove_partial_files,
    writable,
    write_arrays,
)
from prt_torch.bake.subsurface import DipoleParams, frame_subsurface
from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.errors import DamagedArtifact, PrtError
from prt_torch.rig.vertex_frames import cluster_axes, cluster_bones, cluster_vertices, vertex_frames
from prt_torch.rundir import RunDir

if TYPE_CHECKING:
    from prt_torch.config import RunConfig
    from prt_torch.rig.character import Character


@dataclass(frozen=True)
class BlockTask:
    """One task: frames ``[f0, f1)`` of the store at ``dataset`` (absolute path) with their
    ``skin (f1 - f0, J, 4, 4)`` float64 matrices, or a deformable subject's vertex-cache
    ``positions (f1 - f0, V, 3)`` float32 (then traced as they are, frames by :mod:`prt_torch.bake.deformable`)."""

    dataset: str
    f0: int
    f1: int
    skin: np.ndarray
    positions: np.ndarray | None = None


@dataclass(frozen=True)
class BlockStats:
    frames: int
    rays: int
    seconds: float


@dataclass
class BakeResult:
    """What a :func:`run_bake` call did: ``frames``/``rays`` baked now (skipped ones excluded);
    ``repaired``: done frames found damaged and baked again, ``repaired_arrays`` creation-time arrays
    rewritten (both included in ``frames``/not in ``skipped``)."""

    path: Path
    frames: int
    skipped: int
    rays: int
    seconds: float
    repaired: int = 0
    repaired_arrays: tuple[str, ...] = ()

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def rays_per_s(self) -> float:
        return self.rays / self.seconds if self.seconds > 0 else 0.0


#: the per-frame arrays the core bake itself makes (the others come from :data:`prt_torch.bake.extras.BAKE_EXTRAS`)
CORE_RESULTS = ("positions", "normals", "frames", "visibility", "transfer", "subsurface", "peak_directions",
                "peak_visibility")


# -- worker side ---------------------------------------------------------------------------------

@dataclass
class _Context:
    """Per-process state of a store's bake, built once per worker process (cached by path)."""

    group: Any
    arrays: dict[str, Any]
    character: Character
    dense_w: np.ndarray
    labels: np.ndarray
    axes: np.ndarray
    bones: np.ndarray
    rays: RaySet
    params: dict[str, Any]
    extras: list[tuple[BakeExtra, ArraySpec]]  # the method packages' arrays of this bake (prt_torch.bake.extras)
    frame_op: Any = None  # deformable stores: prt_torch.deform.frames.FrameOperator (bake.deformable.frame_operator)


_CONTEXTS: dict[tuple[str, float], _Context] = {}


def _context(dataset: str) -> _Context:
    key = (dataset, os.stat(Path(dataset) / "zarr.json").st_mtime)
    ctx = _CONTEXTS.get(key)
    if ctx is None:
        g = open_for_writing(Path(dataset))
        params = dict(g.attrs["bake"])
        ch = RunDir(dataset).character(expect_hash=str(g.attrs["character_hash"]))
        labels = np.asarray(g["cluster"][:])
        arrays = {name: writable(g[name]) for name in (*PER_FRAME_RESULTS, "done") if name in g}
        ctx = _Context(group=g, arrays=arrays, character=ch, dense_w=ch.dense_weights, labels=labels,
                       axes=np.asarray(g["cluster_axis"][:]), bones=np.asarray(g["cluster_bone"][:]),
                       rays=RaySet.make(int(params["n_rays"]), int(params["order"]), ch.num_vertices,
                                        int(params["seed"]), below_horizon=below_horizon_of(params)),
                       params=params, extras=bake_extras(params, ch.num_vertices, core=CORE_RESULTS))
        if is_deformable(dict(g.attrs)):
            ctx.frame_op = frame_operator(ch, labels)
        _CONTEXTS.clear()
        _CONTEXTS[key] = ctx
    return ctx


def bake_block(task: BlockTask) -> BlockStats:
    """Bake frames ``[f0, f1)`` and write them; ``done`` is set last. Runs in a worker process."""
    from threadpoolctl import threadpool_limits

    from prt_torch.rig.skinning import skin

    t0 = time.perf_counter()
    with threadpool_limits(limits=1):
        ctx = _context(task.dataset)
        p = ctx.params
        ch = ctx.character
        if task.positions is not None:  # a deformable subject: the vertex cache's positions, FrameOperator frames
            if ctx.frame_op is None:
                raise PrtError(f"{task.dataset}: a deformable task for a dataset baked from a skinned character")
            pos = np.asarray(task.positions, dtype=np.float32)
            nrm, frames = posed_frames(ctx.frame_op, pos)
        else:
            pos, nrm = skin(task.skin, ctx.dense_w, ch.rest_vertices, ch.rest_normals)
            assert nrm is not None
            frames = vertex_frames(nrm, task.skin, ctx.labels, ctx.axes, ctx.bones)
        n = task.f1 - task.f0
        V = ch.num_vertices
        vis = np.empty((n, V, int(p["order"]) ** 2), dtype=np.float32)
        tr = np.empty((n, V, int(p["transfer_order"]) ** 2), dtype=np.float32) if p["transfer"] else None
        sss = DipoleParams.from_dict(p["subsurface"]) if p.get("subsurface") else None
        extra: dict[str, np.ndarray] = {}  # subsurface and the extras' arrays, from the same rays and hits
        keep_hits = sss is not None or any(e.needs_hits for e, _ in ctx.extras)
        rays = 0
        for i in range(n):
            res = trace_frame(pos[i], frames[i], ch.faces, ctx.rays, float(p["ray_offset_world"]),
                             transfer_order=int(p["transfer_order"]) if p["transfer"] else None,
                             bounces=int(p["bounces"]) if p["transfer"] else 0, albedo=float(p["albedo"]),
                             max_rays=int(p["vertex_chunk_rays"]), keep_hits=keep_hits)
            vis[i] = res.visibility
            if tr is not None:
                tr[i] = res.transfer
            core: dict[str, np.ndarray] = {}
            if sss is not None:
                if res.transfer is None or res.hits is None:
                    raise PrtError("subsurface needs the frame's transfer and ray hits (bake.transfer: true)")
                core["subsurface"] = frame_subsurface(pos[i], frames[i], ch.faces, ctx.rays, res.hits, res.transfer,
                                                      sss)
            if p.get("peaks"):
                core.update(record_frame({**p["peaks"], "seed": p["seed"]}, task.f0 + i, pos[i], frames[i][:, 2],
                                         ch.faces, float(p["ray_offset_world"])))
            frame = TracedFrame(positions=pos[i], frames=frames[i], faces=ch.faces, rays=ctx.rays, result=res,
                                arrays=core)
            arrays = dict(core)
            for ext, spec in ctx.extras:
                arrays.update(_checked(ext.compute(p, frame), spec))
            for name, a in arrays.items():
                extra.setdefault(name, np.empty((n, *a.shape), dtype=np.float32))[i] = a
            rays += res.n_rays
    g = ctx.arrays  # every chunk written, even one equal to the fill value: a missing chunk is damage
    sl = slice(task.f0, task.f1)
    g["positions"][sl] = pos.astype(np.float32)
    g["normals"][sl] = nrm.astype(np.float32)
    g["frames"][sl] = frames
    g["visibility"][sl] = vis
    if tr is not None:
        g["transfer"][sl] = tr
    for name, a in extra.items():
        g[name][sl] = a
    g["done"][sl] = np.ones(n, dtype=bool)  # last: the block counts as baked only once all its data is in
    return BlockStats(frames=n, rays=rays, seconds=time.perf_counter() - t0)


def _checked(arrays: dict[str, np.ndarray], spec: ArraySpec) -> dict[str, np.ndarray]:
    """A bake extra's arrays of one frame, each of exactly the per-frame shape and dtype it declared."""
    if set(arrays) != set(spec):
        raise PrtError(f"bake extra computed {sorted(arrays)}, declared {sorted(spec)}")
    for name, a in arrays.items():
        shape, dtype = spec[name]
        if a.shape != shape or a.dtype != np.dtype(dtype):
            raise PrtError(f"bake extra array {name!r}: {a.dtype}{list(a.shape)} per frame, declared "
                           f"{dtype}{list(shape)}")
    return arrays


def _worker_init(parent: int) -> None:
    """Pool worker initializer: die with the parent process ``parent`` (pid).

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` makes the kernel kill this worker when its parent dies.
    Everywhere: a daemon thread polls ``os.getppid()`` every 0.2 s and exits the process once it is no
    longer ``parent`` (an orphan is re-parented).
    """
    if sys.platform.startswith("linux"):
        try:
            pr_set_pdeathsig = 1
            ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the watchdog remains
            pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def watchdog() -> None:
        while True:
            time.sleep(0.2)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watchdog, name="prt-parent-watchdog", daemon=True).start()


# -- main side -----------------------------------------------------------------------------------

def _attrs(cfg: RunConfig, plan: BakePlan, offset_world: float) -> dict[str, Any]:
    b = cfg.bake
    bake_params = {**b.store_params(), "ray_offset_world": offset_world}  # the schema's recorded fields
    return {
        "format_version": FORMAT_VERSION,
        "clip_names": plan.clip_names,
        "splits": plan.splits,
        "character_name": plan.character.name,
        "character_hash": plan.character.content_hash(),
        "sh_order": b.order,
        "n_rays": b.n_rays,
        "transfer_order": b.transfer_order if b.transfer else None,
        "bake": bake_params,
        "frames_fingerprint": plan.fingerprint(),
        "conventions": conventions(b.below_horizon),
        "versions": library_versions(),
        "config": cfg.model_dump(mode="json"),
        # positions from the subject's source, FrameOperator frames, k-means clusters (prt_torch.bake.deformable)
        "deformable": plan.deformable,
    }


def _static_arrays(cfg: RunConfig, plan: BakePlan) -> dict[str, np.ndarray]:
    """The arrays written whole when a store is created (deterministic: a repair rewrites them)."""
    b = cfg.bake
    ch = plan.character
    if plan.deformable:  # no bones: k-means of the rest vertices (the single root joint is every cluster's bone)
        labels = deformable_clusters(ch, b.max_clusters, b.seed)
    else:
        labels = cluster_vertices(ch.dense_weights, bandwidth=b.cluster_bandwidth, max_clusters=b.max_clusters,
                                  min_size=b.min_cluster_size, seed=b.seed)
    return {
        "pose": plan.pose.astype(np.float32),
        "clip_id": plan.clip_id.astype(np.int32),
        "frame_index": plan.frame_index.astype(np.int32),
        "faces": ch.faces.astype(np.int32),
        "cluster": labels.astype(np.int32),
        "cluster_axis": cluster_axes(ch.rest_vertices, labels),
        "cluster_bone": cluster_bones(ch.dense_weights, labels),
    }


def _create(path: Path, cfg: RunConfig, plan: BakePlan, attrs: dict[str, Any]) -> None:
    b = cfg.bake
    V = plan.character.num_vertices
    per_frame: dict[str, tuple[tuple[int, ...], str]] = {
        "positions": ((V, 3), "float32"), "normals": ((V, 3), "float32"), "frames": ((V, 3, 3), "float32"),
        "visibility": ((V, b.order**2), "float32"),
    }
    if b.transfer:
        per_frame["transfer"] = ((V, b.transfer_order**2), "float32")
    if b.subsurface is not None:
        per_frame["subsurface"] = ((V, b.transfer_order**2), "float32")
    if b.peaks is not None:
        per_frame["peak_directions"] = ((b.peaks.directions, 3), "float32")
        per_frame["peak_visibility"] = ((V, b.peaks.directions), "float32")
    for _, spec in bake_extras(attrs["bake"], V, core=CORE_RESULTS):
        per_frame.update(spec)
    create_store(path, _static_arrays(cfg, plan), per_frame, plan.n_frames, b.frames_per_task, attrs)


def prepare(cfg: RunConfig, plan: BakePlan | None = None) -> tuple[Path, BakePlan]:
    """Create the store (or check and repair an existing one) and ``character.npz``; returns
    ``(dataset path, plan)``. Holds the run directory's lock meanwhile (:func:`run_bake` holds it for the
    whole bake instead).

    Nothing is written when an existing store or character file belongs to another bake.
    """
    require_embreex()
    plan = make_plan(cfg) if plan is None else plan
    with RunDir(cfg.out_dir.resolve()).lock("bake"):
        path, _ = _prepare(cfg, plan)
    return path, plan


def _prepare(cfg: RunConfig, plan: BakePlan) -> tuple[Path, StoreReport | None]:
    """:func:`prepare` under the lock; also returns the verification report of an existing store."""
    from prt_torch.rig.character import Character

    run = RunDir(cfg.out_dir.resolve())
    path = run.dataset_path
    char_path = run.character_path
    attrs = _attrs(cfg, plan, ray_offset(plan.character.rest_vertices, cfg.bake.ray_offset))
    exists = path.exists()
    if exists:
        try:
            existing = BakedDataset(path, validate=False).attrs
        except DamagedArtifact:
            raise PrtError(f"{path} exists but is not a zarr dataset; move it away or delete it") from None
        check_compatible(path, attrs, existing)
    if char_path.exists():
        try:
            other = Character.load(char_path).content_hash()
        except PrtError:
            other = "unreadable"
        if other != attrs["character_hash"]:
            raise PrtError(f"{char_path} holds another character (hash {other[:12]}); nothing written")
    else:
        plan.character.save(char_path)
    if not exists:
        _create(path, cfg, plan, attrs)
        return path, None
    remove_partial_files(path)
    return path, _repair(path, cfg, plan)


def _repair(path: Path, cfg: RunConfig, plan: BakePlan) -> StoreReport:
    """Verify an existing store (chunks present, checksums) and undo the damage it finds: clear the
    ``done`` entries of damaged blocks (they are then baked as usual) and rewrite damaged creation-time
    arrays from the plan. Returns the verification report (what was damaged)."""
    report = BakedDataset(path).verify(checksums=True)
    if report.ok:
        return report
    if report.static:
        static = _static_arrays(cfg, plan)
        write_arrays(path, {name: static[name] for name in report.static if name in static})
    if report.blocks:
        done = writable(open_for_writing(path)["done"])
        for f0, f1 in report.blocks:
            done[f0:f1] = np.zeros(f1 - f0, dtype=bool)
    return report


def block_tasks(path: Path, plan: BakePlan) -> list[BlockTask]:
    """One task per chunk-aligned block of frames that is not completely done."""
    ds = BakedDataset(path)
    done = ds.done
    fpt = int(ds.array("done").chunks[0])
    tasks = []
    for f0 in range(0, plan.n_frames, fpt):
        f1 = min(plan.n_frames, f0 + fpt)
        if not done[f0:f1].all():
            tasks.append(BlockTask(dataset=str(path), f0=f0, f1=f1, skin=plan.skin[f0:f1],
                                   positions=None if plan.positions is None else plan.positions[f0:f1]))
    return tasks


def _run_local(tasks: list[BlockTask], workers: int) -> Iterator[BlockStats]:
    if workers <= 1 or len(tasks) <= 1:
        for t in tasks:
            yield bake_block(t)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=mp.get_context("spawn"),
                             initializer=_worker_init, initargs=(os.getpid(),)) as ex:
        futures = [ex.submit(bake_block, t) for t in tasks]
        try:
            for fut in as_completed(futures):
                yield fut.result()
        except BaseException:
            for f in futures:
                f.cancel()
            raise


#: seconds a bake waits for the Dask scheduler to answer before it gives up (nothing created yet)
SCHEDULER_TIMEOUT_S = 20.0


def connect_scheduler(scheduler: str) -> Any:
    """A ``dask.distributed.Client`` connected to the scheduler at ``scheduler``; a one-line :class:`PrtError`
    when there is none there (refused, unreachable: within :data:`SCHEDULER_TIMEOUT_S`). :func:`run_bake` connects
    before it creates the run directory or the store, so an unreachable scheduler leaves nothing behind."""
    try:
        from dask.distributed import Client
    except ImportError:
        raise PrtError("the Dask backend needs dask[distributed]") from None
    try:
        return Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S:g}s")
    except (OSError, ValueError, TypeError) as exc:  # timeout, refused, malformed address
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PrtError(f"cannot connect to the Dask scheduler at {scheduler!r} ({msg}); nothing written") from None


def _run_dask(tasks: list[BlockTask], client: Any) -> Iterator[BlockStats]:
    from dask.distributed import KilledWorker, as_completed

    futures = {client.submit(bake_block, t, pure=False): t for t in tasks}
    for fut in as_completed(list(futures)):
        try:
            st = fut.result()
        except KilledWorker as exc:  # workers died running this block more often than the scheduler allows
            t = futures[fut]
            raise PrtError(f"Dask workers died {exc.allowed_failures + 1} time(s) baking frames {t.f0}..{t.f1 - 1} "
                           f"(distributed.scheduler.allowed-failures = {exc.allowed_failures}); the blocks done are "
                           f"kept: run prt bake again to resume") from None
        yield st


def run_bake(
    cfg: RunConfig,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    on_block: Callable[[BlockStats], None] | None = None,
) -> BakeResult:
    """Bake (or resume) a run's dataset; see :func:`bake`. Returns what was done and how fast.

    Holds the run directory's lock throughout: another bake of it is a one-line :class:`PrtError`.
    """
    from prt_torch import limits

    require_embreex()
    if workers is not None and workers < 1:
        raise PrtError(f"workers must be >= 1, got {workers}")
    scheduler = scheduler if scheduler is not None else cfg.bake.scheduler
    # the scheduler is reached before anything is written (a cloth run's simulation, the run directory, the store)
    client = connect_scheduler(scheduler) if scheduler else None
    try:
        source = source_of(cfg)
        if source is not None:  # a deformable subject: e.g. simulate (resumably) what a cloth's vertex cache lacks
            source.prepare(cfg, progress)
        plan = make_plan(cfg)  # before the lock: a bad config creates nothing
        b = cfg.bake
        # the vertex count of a glTF character is known only now: one task's arrays must fit in memory
        limits.check_bake_task_memory(min(b.frames_per_task, plan.n_frames), plan.character.num_vertices, b.order,
                                      b.transfer_order if b.transfer else None,
                                      matrix_order=b.matrix_order if b.transfer_matrix else None, n_rays=b.n_rays,
                                      subsurface=b.subsurface is not None)
        with RunDir(cfg.out_dir.resolve()).lock("bake"):
            return _run_bake(cfg, plan, workers, client, progress, on_block)
    finally:
        if client is not None:
            client.close()


def _run_bake(cfg: RunConfig, plan: BakePlan, workers: int | None, client: Any, progress: bool,
              on_block: Callable[[BlockStats], None] | None) -> BakeResult:
    path, report = _prepare(cfg, plan)
    repaired = sum(f1 - f0 for f0, f1 in report.blocks) if report is not None else 0
    repaired_arrays = tuple(report.static) if report is not None else ()
    if report is not None and not report.ok:
        print(f"repairing {path}: {report.summary()}; re-baking {repaired} frame(s) in {len(report.blocks)} "
              f"block(s)" + (f", rewriting {', '.join(repaired_arrays)}" if repaired_arrays else ""),
              file=sys.stderr)
    tasks = block_tasks(path, plan)
    total = plan.n_frames
    todo = sum(t.f1 - t.f0 for t in tasks)
    if workers is None:
        workers = cfg.bake.workers or os.cpu_count() or 1
    if workers < 1:
        raise PrtError(f"workers must be >= 1, got {workers}")
    stream = _run_dask(tasks, client) if client is not None else _run_local(tasks, workers)
    frames = rays = 0
    t0 = time.perf_counter()
    with _progress(progress, total, total - todo, "Dask" if client is not None else f"{workers} worker(s)") \
            as advance:
        for st in stream:
            frames += st.frames
            rays += st.rays
            advance(st.frames, frames, rays, time.perf_counter() - t0)
            if on_block is not None:
                on_block(st)
    ds = BakedDataset(path)
    if ds.complete:  # every task came back: a ``*.partial`` left now is a write of a worker killed mid-chunk
        remove_partial_files(path)
        RunDir(path).mark_done("bake", ds.key())
    return BakeResult(path=path, frames=frames, skipped=total - todo, rays=rays, seconds=time.perf_counter() - t0,
                      repaired=repaired, repaired_arrays=repaired_arrays)


def bake(cfg: RunConfig, workers: int | None = None, scheduler: str | None = None, progress: bool = True) -> Path:
    """Bake the ground-truth dataset of a run config into ``<out_dir>/dataset.zarr``; returns its path.

    Args:
        cfg: the run config (``character`` and ``bake`` sections).
        workers: local worker processes (default ``cfg.bake.workers``, 0 there meaning one per
            core); 1 bakes in this process.
        scheduler: Dask scheduler address (``tcp://HOST:PORT``); overrides the local pool.
        progress: show a rich progress bar with frames/s and Mrays/s.
    """
    return run_bake(cfg, workers=workers, scheduler=scheduler, progress=progress).path


class _progress:
    """Context manager yielding ``advance(n, frames_now, rays_now, seconds)``."""

    def __init__(self, enabled: bool, total: int, completed: int, backend: str) -> None:
        self.enabled = enabled
        self.total = total
        self.completed = completed
        self.backend = backend
        self._progress: Any = None

    def __enter__(self) -> Callable[[int, int, int, float], None]:
        if not self.enabled:
            return lambda *a: None
        from prt_torch.progress import progress_bar

        self._progress = progress_bar("bake ({task.fields[backend]})", ("frames", "{task.fields[rate]}"),
                                      remaining=True)
        self._progress.start()
        self._task = self._progress.add_task("bake", total=self.total, completed=self.completed,
                                             backend=self.backend, rate="")

        def advance(n: int, frames: int, rays: int, seconds: float) -> None:
            s = max(seconds, 1e-9)
            self._progress.update(self._task, advance=n,
                                  rate=f"{frames / s:.2f} frames/s  {rays / s / 1e6:.2f} Mrays/s")

        return advance

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()
