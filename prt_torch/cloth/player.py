"""The run-time player of a DEFORMABLE run (cloth, issue 11): cached positions -> frames + visibility -> RPO shading.

numpy + onnxruntime only (never torch). Per frame (:meth:`DeformablePlayer.compute`)::

    positions (B, V, 3) and vertex-last (B, 3, V) [+ body features (B, Ab), the cape]   (a Sequence holds both)
        --numpy FrameOperator.frames_soa--> frames (B, 9, V), normals; view dirs (B, 3, V)        ("pose")
    [fused]   ORT positions_fused.onnx(positions, frames, view dirs, lobes, RPO): dihedral angles -> model ->
              RPO shading -> radiance (B, V, 3), vertex axes in the export's cluster order like the skinned
              fused graph (frames / view dirs permuted in, radiance back)                                ("fused")
              (features="numpy": the numpy dihedral angles into fused.onnx, the pose-in fused graph)
    [split]   features="numpy" (default): numpy dihedral angles (DihedralSoA, vertex-last) [+ body] -> ORT
              visibility.onnx (the pose graph: the same model) --> visibility (B, V, C)    ("visibility")
              features="graph": ORT positions.onnx: dihedral angles -> model --> visibility (B, V, C)
              a run shipping a LOCAL network (export.json ``local``): frames first, then the neighbour offsets
              (numba; the local package's hook, prt_torch.player.sources) -> ORT local.onnx --> visibility (B, V, C);
              split and pipeline only
              ORT shading.onnx (the skinned player's Player.shade)--> radiance (B, V, 3)     ("shading")
    [overlap] split, with the features + model on a worker thread while numpy computes the frames
    [pipeline] playback of a sequence (:meth:`DeformablePlayer.compute_stream`): a worker thread computes frame
              i + 1's features, visibility and frames while the main thread shades frame i; every onnxruntime
              session runs on one thread (the two stages fill two cores). Throughput, at one frame of latency: the
              next frame's positions must be known one frame ahead (a cache, or a simulation running a frame ahead,
              as engines run the simulation ahead of the renderer). Single frames (:meth:`compute`) run as split.
              A local run: two WHOLE frames in flight, one per worker thread (its stages do not split evenly),
              two frames of latency (:meth:`DeformablePlayer._stream_whole_frames`).

The numpy features are ~4x faster than the positions graph's (onnxruntime's Gather of the 4 corners of 22k edges
is ~0.7 ms; numpy's ``take`` of contiguous coordinate rows ~0.15 ms: :mod:`prt_torch.deform.dihedral_soa`), and the
pose graph is the positions graph's model exactly (same export, same weights); ``prt bench play`` measures both.

Everything after the visibility is the skinned player's (:class:`prt_torch.player.Player`: lighting, RPO catalogue,
shading graph, tone map, renderer, video writer, timings): this class only replaces the posing (positions come from
the run's vertex cache ``simulation.zarr``, :class:`prt_torch.cloth.cache.VertexCache`, or an array) and the
visibility input (positions instead of pose features).

Embedding::

    p = DeformablePlayer("runs/flag")
    p.play("wind_heldout", out="flag.mp4")                 # a cached sequence
    state, radiance = p.compute_positions(positions[:1])     # (1, V, 3) positions
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import DamagedArtifact, MissingArtifact, PrtError, check
from prt_torch.player.player import Player, PlayResult, sequence_view
from prt_torch.player.posing import PoseBatch
from prt_torch.player.timing import FrameTimer
from prt_torch.rundir import RunDir
from prt_torch.runtime.session import OrtGraph
from prt_torch.shapes import check_shape

#: graph modes of the deformable player
DEFORMABLE_MODES = ("fused", "split", "overlap", "pipeline")
#: where split / overlap compute the dihedral angles: numpy (DihedralSoA, then the pose graph) or positions.onnx
FEATURE_MODES = ("numpy", "graph")
#: playback rate when the vertex cache records none
DEFAULT_FPS = 30.0


@dataclass
class Sequence:
    """A deformable sequence to play: ``positions (T, V, 3)`` float32 of the whole subject (the positions graph's
    layout) and the same vertex-last ``positions_soa (T, 3, V)`` (the frames' layout), ``body (T, Ab)`` body features
    (the cape; ``None``: none), its ``name`` and ``fps``. Slicing gives the frames ``(positions, positions_soa, body)``
    (what :meth:`DeformablePlayer.compute` takes, the ``locals`` of :meth:`Player.play`)."""

    name: str
    positions: np.ndarray
    positions_soa: np.ndarray
    body: np.ndarray | None = None
    fps: float = DEFAULT_FPS

    def __len__(self) -> int:
        return int(self.positions_soa.shape[0])

    def __getitem__(self, s: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        return self.positions[s], self.positions_soa[s], (None if self.body is None else self.body[s])


class DeformablePlayer(Player):
    """Plays cached sequences of an exported deformable run (see the module docstring).

    Args: those of :class:`Player` except ``graph``: ``"split"`` (default: the visibility, then the shading graph;
    the fastest measured per single frame on the 7.7k flag), ``"fused"`` (one positions -> radiance call),
    ``"overlap"`` (split, the features + model on a worker thread while numpy computes the frames) or
    ``"pipeline"`` (sequence playback two frames in flight: :meth:`compute_stream`; every session on one thread,
    ``threads`` is ignored); ``crowd_chunk`` is not used;
    ``features``: ``"numpy"`` (default, fastest measured: :class:`DihedralSoA` + the pose graph) or ``"graph"``
    (``positions.onnx``) for split / overlap; ``local``: ``None`` (default) plays the shipped local network when
    the export has one (``export.json`` ``local``: split and pipeline only), ``False`` the per-cluster model
    anyway (benchmarks), ``True`` insists on the local network.
    """

    def __init__(self, run_dir: str | os.PathLike[str] | RunDir, env: str | os.PathLike[str] | None = None,
                 brdf: str | None = None, graph: str = "split", threads: int = 2,
                 window_size: tuple[int, int] = (480, 640), exposure: Any = None, n_lobes: int = 3,
                 blas_threads: int | None = 1, spinning: bool = False, device: str = "cpu",
                 features: str = "numpy", local: bool | None = None) -> None:
        from prt_torch.cloth.deform_data import DeformData
        from prt_torch.deform.dihedral_soa import DihedralSoA

        check(graph in DEFORMABLE_MODES, f"unknown graph mode {graph!r} for a deformable run: expected one of "
                                         f"{list(DEFORMABLE_MODES)}")
        check(features in FEATURE_MODES, f"unknown features mode {features!r}: expected one of {list(FEATURE_MODES)}")
        if graph == "pipeline":  # two stages on two threads: one onnxruntime thread each (no oversubscription)
            threads = 1
        super().__init__(run_dir, env=env, brdf=brdf, graph="split", threads=threads, window_size=window_size,
                         exposure=exposure, n_lobes=n_lobes, blas_threads=blas_threads, spinning=spinning,
                         device=device)
        self.mode = graph
        run = self.bundle.run
        meta = self.bundle.meta.get("deformable")
        check(isinstance(meta, dict), f"{run.path} is not an exported deformable run (no 'deformable' entry in "
                                      f"{run.export_json.name}): play it with --clip, or run `prt export` on it")
        self.deform = DeformData.load(run.deform_path)  # verified against export.json's sha256 by the bundle
        self.n_body = self.deform.n_body_features
        self.features = features
        self.dihedral = DihedralSoA(self.deform.edges, self.bundle.n_vertices)
        self.positions_graph = OrtGraph(run.positions_graph_path, threads=threads, spinning=spinning, device=device)
        md = self.positions_graph.metadata
        check(md.get("prt.character_hash") == self.bundle.meta["character_hash"],
              f"{run.positions_graph_path.name}: exported for another subject: run `prt export {run.path} --force`")
        self.positions_fused: OrtGraph | None = None
        if graph == "fused" and features == "graph":
            check("fused_file" in meta, f"{run.export_json}: no positions_fused graph (an older export): run `prt "
                                        f"export {run.path} --force`, or play with --graph split")
            self.positions_fused = OrtGraph(run.positions_fused_path, threads=threads, spinning=spinning,
                                            device=device)
        self._vis_overlap: OrtGraph | None = None
        self._threads, self._spinning = threads, spinning
        #: the shipped local visibility network (export.json ``local``; None: the per-cluster model plays)
        self.local_graph: OrtGraph | None = None
        shipped = self.bundle.meta.get("local")
        check(local is not True or isinstance(shipped, dict),
              f"{run.path} ships no local visibility model (train.local.default): play it without local=True")
        if isinstance(shipped, dict) and local is not False:
            from prt_torch.player.sources import network_input

            check(graph in ("split", "pipeline"),
                  f"{run.path} ships a local visibility model (local_{shipped.get('kind')}), which needs the frames "
                  f"first: play it with --graph split or pipeline, not {graph}")
            self.local_offsets = network_input("local", run)  # the local package's hook (local.npz neighbours)
            check(self.local_offsets.n_vertices == self.bundle.n_vertices,
                  f"{run.local_data_path.name}: {self.local_offsets.n_vertices} vertices, the run's subject "
                  f"{self.bundle.n_vertices}: run `prt export {run.path} --force`")
            self.local_graph = OrtGraph(run.local_graph_path, threads=threads, spinning=spinning, device=device)

    # -- inputs ---------------------------------------------------------------------------------
    def sequences(self) -> list[str]:
        """The sequences of the run's vertex cache."""
        return list(self._cache().sequences())

    def _cache(self) -> Any:
        try:
            from prt_torch.cloth.cache import VertexCache
        except ImportError as exc:  # a player-only install has no zarr
            raise PrtError(f"reading the run's vertex cache needs the bake extra (zarr): {exc}; or play a positions "
                           f"array (DeformablePlayer.make_sequence)") from None

        path = self.bundle.run.simulation
        check(path.exists(), f"{path}: no vertex cache in this run (run `prt simulate` / `prt bake` on its config)")
        return VertexCache(path)

    def sequence(self, name: str) -> Sequence:
        """A cached sequence of the run by name (positions and, for the cape, body features), checked."""
        cache = self._cache()
        names = list(cache.sequences())
        check(name in names, f"unknown sequence {name!r}: the run's vertex cache has {names}")
        pos = np.asarray(cache.positions(name), dtype=np.float32)
        body = cache.body_features(name) if self.n_body else None
        rate = getattr(cache, "fps", None)  # the cache's frame rate when it records one
        fps = float((rate(name) if callable(rate) else rate) or DEFAULT_FPS)
        return self.make_sequence(pos, body, name=name, fps=fps)

    def make_sequence(self, positions: np.ndarray, body: np.ndarray | None = None, name: str = "positions",
                      fps: float = DEFAULT_FPS) -> Sequence:
        """A :class:`Sequence` of ``positions (T, V, 3)`` (and ``body (T, Ab)``), checked: one-line
        :class:`PrtError` for a wrong shape or vertex count, NaN/Inf, missing or extra body features."""
        v = self.bundle.n_vertices
        pos = np.asarray(positions, dtype=np.float32)
        check_shape(pos, "T V 3", name="positions")
        check(pos.shape[0] >= 1, f"positions must be (T, V, 3) with T >= 1, got shape {pos.shape}")
        check(pos.shape[1] == v, f"positions have {pos.shape[1]} vertices, the run's subject {v}")
        bad = ~np.isfinite(pos).all(axis=(1, 2))
        check(not bad.any(), f"positions contain NaN or Inf (first at frame {int(np.argmax(bad))})")
        if self.n_body:
            check(body is not None, f"this run takes {self.n_body} body features per frame with the positions")
            b = np.asarray(body, dtype=np.float32)
            check_shape(b, (pos.shape[0], self.n_body), name="body features")
            check(bool(np.isfinite(b).all()), "body features contain NaN or Inf")
            body = np.ascontiguousarray(b)
        else:
            check(body is None, "this run takes no body features")
        pos = np.ascontiguousarray(pos)
        return Sequence(name, pos, np.ascontiguousarray(pos.transpose(0, 2, 1)), body, float(fps))

    # -- per-frame path ---------------------------------------------------------------------------
    def frames(self, positions_soa: np.ndarray) -> PoseBatch:
        """numpy vertex frames, normals and view directions of ``positions_soa (B, 3, V)`` (vertex-last
        :class:`PoseBatch`; ``features`` is empty: the positions graph takes the positions)."""
        p = np.ascontiguousarray(positions_soa, dtype=np.float32)
        frames, normals = self.deform.operator.frames_soa(p)
        view = np.subtract(self.eye.reshape(1, 3, 1), p)
        view *= 1.0 / np.maximum(np.sqrt(np.einsum("bkv,bkv->bv", view, view)), 1e-12)[:, None]
        return PoseBatch(p, normals, frames, view, np.zeros((p.shape[0], 0), np.float32))

    def pose_features(self, positions_soa: np.ndarray, body: np.ndarray | None = None) -> np.ndarray:
        """``positions (B, 3, V)`` [+ ``body (B, Ab)``] -> the model's input ``(B, E [+ Ab])``: numpy dihedral
        angles (:class:`~prt_torch.deform.dihedral_soa.DihedralSoA`), body features appended (the positions
        graph's rule)."""
        f = self.dihedral(positions_soa)
        return np.concatenate([f, np.asarray(body, np.float32)], axis=1) if self.n_body else f

    def _visibility_numpy(self, positions_soa: np.ndarray, body: np.ndarray | None,
                          graph: OrtGraph | None = None) -> np.ndarray:
        g = graph or self.bundle.graphs["visibility"]
        return g.run_unchecked({"pose": self.pose_features(positions_soa, body)})[0]

    def _visibility(self, positions: np.ndarray, positions_soa: np.ndarray, body: np.ndarray | None,
                    graph: OrtGraph | None = None) -> np.ndarray:
        """``(B, V, C)`` visibility by the player's ``features`` mode (numpy angles + the pose graph, or
        ``positions.onnx``); ``graph``: another session of that file (the overlap worker's)."""
        if self.features == "graph":
            return (graph or self.positions_graph).run_unchecked(self._vis_feeds(positions, body))[0]
        return self._visibility_numpy(positions_soa, body, graph)

    def _local_visibility(self, positions_soa: np.ndarray, state: PoseBatch) -> np.ndarray:
        """``(B, V, C)`` visibility of the shipped local network: the neighbour offsets of the positions in
        ``state``'s frames (numba), then ``local.onnx`` (one session, also shared by the pipeline's workers)."""
        x = self.local_offsets(positions_soa, state.frames)
        return self.local_graph.run_unchecked({"offsets": x})[0]  # type: ignore[union-attr]

    def _vis_feeds(self, positions: np.ndarray, body: np.ndarray | None) -> dict[str, np.ndarray]:
        feeds = {"positions": np.ascontiguousarray(positions, dtype=np.float32)}
        if self.n_body:
            feeds["body"] = np.ascontiguousarray(body, dtype=np.float32)
        return feeds

    def visibility_from_positions(self, positions: np.ndarray, body: np.ndarray | None = None,
                                  checked: bool = True) -> np.ndarray:
        """``positions (B, V, 3)`` [+ ``body (B, Ab)``] -> ``(B, V, C)`` local visibility (ORT positions graph;
        a run shipping a local network: its frames, offsets and ``local.onnx``)."""
        if self.local_graph is not None:
            pos = np.asarray(positions, np.float32)
            if checked:  # before the transpose, which needs three axes
                check(pos.ndim == 3 and pos.shape[1:] == (self.bundle.n_vertices, 3) and np.isfinite(pos).all(),
                      f"positions must be finite (B, {self.bundle.n_vertices}, 3), got {pos.shape}")
            p = np.ascontiguousarray(pos.transpose(0, 2, 1))
            return self._local_visibility(p, self.frames(p))
        feeds = self._vis_feeds(positions, body)
        g = self.positions_graph
        return g.run(feeds)["visibility"] if checked else g.run_unchecked(feeds)[0]

    def compute_positions(self, positions: np.ndarray, body: np.ndarray | None = None,
                          timer: FrameTimer | None = None, checked: bool = True) -> tuple[PoseBatch, np.ndarray]:
        """The whole per-frame path for ``positions (B, V, 3)`` -> (posed batch, radiance (B, V, 3))."""
        if checked:
            seq = self.make_sequence(positions, body)
            return self.compute(seq[:], timer)
        p = np.ascontiguousarray(positions, dtype=np.float32)
        return self.compute((p, np.ascontiguousarray(p.transpose(0, 2, 1)), body), timer)

    def compute(self, frame: Any, timer: FrameTimer | None = None) -> tuple[PoseBatch, np.ndarray]:
        """``frame = (positions (B, V, 3), positions_soa (B, 3, V), body (B, Ab) | None)`` (a slice of a
        :class:`Sequence`, checked) -> (posed batch, radiance (B, V, 3)); the per-frame path of :meth:`Player.play`."""
        positions, positions_soa, body = frame
        t0 = time.perf_counter()
        if self.mode == "fused":
            state = self.frames(positions_soa)
            o = self.vertex_order
            if self.positions_fused is not None:  # features="graph": positions_fused.onnx
                g, inputs = self.positions_fused, self._vis_feeds(positions, body)
            else:  # numpy features into the pose-in fused graph (fused.onnx, the same model and shading)
                g, inputs = self.bundle.graphs["fused"], {"pose": self.pose_features(positions_soa, body)}
            feeds = {**inputs, "frames": state.in_order("frames", o), "view_dirs": state.in_order("view_dirs", o),
                     **self._light_feeds()}
            t1 = time.perf_counter()
            out = self._to_original(g.run_unchecked(feeds)[0])
            if timer is not None:
                timer.add("pose", t1 - t0)
                timer.add("fused", time.perf_counter() - t1)
            return state, out
        if self.mode == "overlap":
            fut = self._worker().submit(self._visibility, positions, positions_soa, body, self._vis_overlap)
            state = self.frames(positions_soa)
            t1 = time.perf_counter()
            vis = fut.result()
        else:
            state = self.frames(positions_soa)
            t1 = time.perf_counter()
            vis = self._local_visibility(positions_soa, state) if self.local_graph is not None else \
                self._visibility(positions, positions_soa, body)
        t2 = time.perf_counter()
        out = self.shade(state, visibility=vis, checked=False)
        if timer is not None:
            timer.add("pose", t1 - t0)
            timer.add("visibility", t2 - t1)  # overlap: the part of the model call not hidden behind the frames
            timer.add("shading", time.perf_counter() - t2)
        return state, out

    def _stage(self, frame: Any) -> tuple[PoseBatch, np.ndarray]:
        """The pipeline's worker stage for ``frame = (positions, positions_soa, body)``: (posed batch, visibility)."""
        positions, positions_soa, body = frame
        vis = self._visibility(positions, positions_soa, body, self._vis_overlap)
        return self.frames(positions_soa), vis

    def compute_stream(self, frames: Any, n: int, timer: FrameTimer | None = None) -> Iterator[tuple[PoseBatch,
                                                                                                    np.ndarray]]:
        """``(state, radiance)`` of frames ``0 .. n-1`` of ``frames`` (a :class:`Sequence`), in order. Mode
        ``"pipeline"``: frame ``i + 1``'s stage (:meth:`_stage`: features, visibility, frames) runs on the worker
        thread while this thread shades frame ``i`` (timer steps ``"visibility"``: the part of the stage not hidden
        behind the shading and rendering, as in overlap; ``"shading"``); other modes: :meth:`compute` per frame."""
        if self.mode != "pipeline":
            yield from super().compute_stream(frames, n, timer)
            return
        if self.local_graph is not None:
            yield from self._stream_whole_frames(frames, n, timer)
            return
        pool = self._worker()
        fut = pool.submit(self._stage, frames[0:1]) if n > 0 else None
        for i in range(n):
            t0 = time.perf_counter()
            state, vis = fut.result()  # type: ignore[union-attr]
            if i + 1 < n:
                fut = pool.submit(self._stage, frames[i + 1:i + 2])
            t1 = time.perf_counter()
            out = self.shade(state, visibility=vis, checked=False)
            if timer is not None:
                timer.add("visibility", t1 - t0)
                timer.add("shading", time.perf_counter() - t1)
            yield state, out

    def _stream_whole_frames(self, frames: Any, n: int, timer: FrameTimer | None) -> Iterator[tuple[PoseBatch,
                                                                                                    np.ndarray]]:
        """Pipeline playback of a local run: two whole frames in flight, one per worker (the two cores), yielded in
        order. Its stages do not split evenly (the frames feed the offsets, which feed the network), so each worker
        runs a whole frame (:meth:`compute`'s split path) rather than one stage: two frames of latency. Timer step
        ``"visibility"``: the main thread's wait, the part of the workers' compute not hidden behind its own work
        (rendering)."""
        from collections import deque

        pool = self._worker()
        inflight = deque(pool.submit(self.compute, frames[i:i + 1]) for i in range(min(self.IN_FLIGHT, n)))
        for i in range(n):
            t0 = time.perf_counter()
            state, out = inflight.popleft().result()
            if i + self.IN_FLIGHT < n:
                j = i + self.IN_FLIGHT
                inflight.append(pool.submit(self.compute, frames[j:j + 1]))
            if timer is not None:  # the main thread's wait: the part of the workers' compute not hidden
                timer.add("visibility", time.perf_counter() - t0)
            yield state, out

    #: frames in flight in a local run's pipeline (one per worker thread: the machine's two cores)
    IN_FLIGHT = 2

    def _worker(self) -> Any:
        """The worker thread of the overlap and pipeline modes and its one-thread session of the visibility graph
        (``positions.onnx`` or ``visibility.onnx`` by ``features``), created on first use."""
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            if self.local_graph is not None:  # pipeline: whole frames on two workers, sharing the sessions
                self._pool = ThreadPoolExecutor(max_workers=self.IN_FLIGHT, thread_name_prefix="prt-frame")
                return self._pool
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prt-visibility")
            path = self.positions_graph.path if self.features == "graph" else self.bundle.graphs["visibility"].path
            self._vis_overlap = OrtGraph(path, threads=1, spinning=self._spinning, device=self.device)
        return self._pool

    def frame_sequence(self, seq: Sequence) -> None:
        """Aim the camera at the whole sequence (:func:`~prt_torch.player.player.sequence_view`: the box of every
        position of every frame, from the side the cloth's front faces)."""
        self.center, self.radius, self.camera_azimuth = sequence_view(seq.positions, self.character.faces)

    def clip_locals(self, clip: Any, fps: float | None = None) -> Any:
        """The frames :meth:`Player.play` iterates: the :class:`Sequence` ``clip`` (a name: the cached one)."""
        return clip if isinstance(clip, Sequence) else self.sequence(str(clip))

    def play(self, sequence: str | Sequence, out: str | os.PathLike[str] | None = None,  # type: ignore[override]
             png_dir: str | os.PathLike[str] | None = None, max_frames: int | None = None,
             fps: float | None = None, timings: str | os.PathLike[str] | None = None,
             show: bool = False, progress: bool = True) -> PlayResult:
        """Play a cached sequence (name) or a :class:`Sequence` (:meth:`make_sequence`) like :meth:`Player.play`;
        ``fps``: the video rate (default: the sequence's; frames are not resampled)."""
        seq = self.clip_locals(sequence)
        self.frame_sequence(seq)
        return super().play(seq, out=out, png_dir=png_dir, max_frames=max_frames, fps=fps or seq.fps,
                            timings=timings, show=show, progress=progress)


def is_deformable_export(run_dir: str | os.PathLike[str] | RunDir) -> bool:
    """Whether the run's export is a deformable one (``export.json`` has a ``deformable`` entry; unverified)."""
    run = RunDir.of(run_dir)
    try:
        return isinstance(run.read_json(run.export_json).get("deformable"), dict)
    except (MissingArtifact, DamagedArtifact):
        return False
