"""Simulate a cloth run's sequences into its vertex cache (``prt simulate``; layout in :mod:`prt_torch.cloth.cache`).

One sequence (:func:`simulate_sequence`): reset the MuJoCo model (:mod:`prt_torch.cloth.engine`), then
``settle_frames`` unrecorded frames (cape: the body blends from the bind pose to the sequence's first frame over
the first half, then holds it; flag: the wind blows from ``t = -settle / fps``, its speed rising from 0 over the
first half), then one recorded frame per
body frame / wind frame. Every frame is ``substeps`` MuJoCo steps; the kinematic targets (pinned vertices,
collider bones) are interpolated linearly between frames (quaternions: normalised lerp). After every frame the
state is checked (:func:`check_state`): NaN/inf, a vertex faster than ``max_speed``, an edge stretched beyond
``1 + max_strain`` times its rest length, or a MuJoCo solver warning is a one-line :class:`PrtError` naming the
sequence and the frame (a blow-up: smaller timestep, i.e. more ``substeps``, or softer material).

The whole run (:func:`simulate`) is resumable: the store is created once with every sequence's arrays; a
sequence's ``done`` flag is written after its arrays, and done sequences are never simulated again. A store
simulated with another configuration (:func:`simulation_key`) is refused without writing anything. MuJoCo on
one thread is deterministic: the same config gives bit-identical caches.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.cloth.cache import FORMAT, VertexCache
from prt_torch.cloth.subject import ClothSubject
from prt_torch.errors import PrtError

if TYPE_CHECKING:
    from prt_torch.cloth.engine import Engine, Kinematics
    from prt_torch.config import RunConfig

#: frames per chunk of a positions array
CHUNK_FRAMES = 16


@dataclass
class SequenceResult:
    """One simulated sequence: ``positions (T, V, 3)`` float32 of the whole subject and the body's
    ``body_features (T, A)`` float32 (``None`` for the flag); ``steps`` MuJoCo steps taken, ``seconds`` wall."""

    name: str
    positions: np.ndarray
    body_features: np.ndarray | None
    steps: int
    seconds: float


def simulation_key(cfg: RunConfig, subject: ClothSubject) -> dict[str, Any]:
    """Everything that changes the simulated numbers: the cloth section (less ``append_pose``), the body and its
    motions (cape), the sequences, the MuJoCo version and the cache format."""
    import mujoco

    key: dict[str, Any] = {"format": FORMAT, "cloth": subject.cloth.simulation_key(), "fps": subject.fps,
                           "splits": subject.splits, "mujoco": mujoco.__version__}
    if subject.body is not None:
        key["character"] = cfg.character.model_dump(mode="json", include={"source", "density", "height", "fps",
                                                                          "train_clips", "heldout_clips", "motions"})
        key["body_hash"] = subject.body.content_hash()
        key["motion_hash"] = {n: _array_hash(c.local) for n, c in subject.body_clips.items()}
    return key


def _array_hash(a: np.ndarray) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.float64).tobytes()).hexdigest()


# -- one sequence --------------------------------------------------------------------------------------
def check_state(engine: Engine, x: np.ndarray, sequence: str, frame: int) -> None:
    """Raise a one-line blow-up :class:`PrtError` naming ``sequence`` and ``frame`` (module docstring)."""
    c = engine.subject.cloth
    v = engine.velocities()
    where = f"cloth simulation blew up in sequence {sequence!r} at frame {frame}"
    hint = "use more cloth.substeps (a smaller timestep) or a softer cloth (young, edge_timeconst)"
    warn = engine.warnings()
    if warn:
        raise PrtError(f"{where}: MuJoCo warning {warn[0]}; {hint}")
    if not (np.isfinite(x).all() and np.isfinite(v).all()):
        raise PrtError(f"{where}: NaN or inf positions; {hint}")
    speed = float(np.sqrt(np.max(np.einsum("ij,ij->i", v, v))))
    if speed > c.max_speed:
        raise PrtError(f"{where}: a vertex moves at {speed:.3g} m/s > max_speed {c.max_speed:g}; {hint}")
    e = engine.subject.unique_edges
    rest = np.linalg.norm(engine.subject.cloth_rest[e[:, 0]] - engine.subject.cloth_rest[e[:, 1]], axis=1)
    strain = float(np.max(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / rest)) - 1.0
    if strain > c.max_strain:
        raise PrtError(f"{where}: an edge is stretched {100 * strain:.0f}% > max_strain {100 * c.max_strain:.0f}%; "
                       f"{hint}")


def _blend_skin(skin0: np.ndarray, s: float) -> np.ndarray:
    """Skin matrices between the bind pose (identity, ``s = 0``) and ``skin0`` (``s = 1``): rotation by slerp
    from the identity, translation linear."""
    from scipy.spatial.transform import Rotation

    out = np.array(skin0, dtype=np.float64, copy=True)
    rv = Rotation.from_matrix(skin0[:, :3, :3]).as_rotvec()
    out[:, :3, :3] = Rotation.from_rotvec(rv * s).as_matrix()
    out[:, :3, 3] = skin0[:, :3, 3] * s
    return out


def simulate_sequence(subject: ClothSubject, name: str, engine: Engine | None = None,
                      on_frame: Callable[[int, int], None] | None = None) -> SequenceResult:
    """Simulate sequence ``name`` of ``subject`` (module docstring); ``on_frame(done, total)`` after each frame
    (settle frames included)."""
    import time

    from prt_torch.cloth.engine import Engine, engine_kinematics
    from prt_torch.cloth.wind import WindField

    t_start = time.perf_counter()
    engine = Engine(subject) if engine is None else engine
    engine.reset()
    c = subject.cloth
    T = subject.n_frames(name)
    settle = c.settle_frames
    body_pos: np.ndarray | None = None
    feats: np.ndarray | None = None
    if subject.body is not None:
        poses = subject.body_sequence(name).poses
        skins = poses.skin
        half = max(1, settle // 2)

        def key(k: int) -> Kinematics:  # kinematic targets at the end of frame k (k < 0: settle)
            if k < 0:
                s = min(1.0, (k + settle + 1) / half)
                return engine_kinematics(engine, _blend_skin(skins[0], s))
            return engine_kinematics(engine, skins[k])

        body_pos, _ = subject.body.skin_mesh(poses)
        feats = np.asarray(poses.features, dtype=np.float32)
        wind = WindField.still()
        start = engine_kinematics(engine, np.repeat(np.eye(4)[None], subject.body.num_joints, axis=0))
    else:
        fixed = engine_kinematics(engine, None)

        def key(k: int) -> Kinematics:
            return fixed

        wind = WindField.from_pattern(subject.winds[name], c.seed)
        start = fixed
    engine.set_kinematics(start)
    n = len(subject.cloth_rest)
    out = np.empty((T, subject.n_vertices, 3), dtype=np.float32)
    if body_pos is not None:
        out[:, : subject.n_body] = body_pos
    sub = c.substeps
    prev = start
    total = settle + T
    for i, k in enumerate(range(-settle, T)):
        target = key(k)
        t0 = (k - 1) / subject.fps
        ramp = min(1.0, (k + settle + 1) / max(1, settle // 2)) if k < 0 else 1.0  # the wind rises during settling
        for s in range(sub):
            engine.set_kinematics(prev.lerp(target, s / sub), prev.lerp(target, (s + 1) / sub))
            engine.step(wind, t0 + s / (sub * subject.fps), ramp)
        prev = target
        x = engine.positions()
        check_state(engine, x, name, k)
        if k >= 0:
            out[k, subject.n_body: subject.n_body + n] = x
        if on_frame is not None:
            on_frame(i + 1, total)
    return SequenceResult(name, out, feats, total * sub, time.perf_counter() - t_start)


# -- the store -----------------------------------------------------------------------------------------
def _create_store(path: Path, subject: ClothSubject, attrs: dict[str, Any]) -> None:
    """Create the complete store atomically (:func:`prt_torch.bake.store.new_store`: a temporary sibling, then a
    rename that replaces nothing)."""
    from prt_torch.bake.store import new_store, store_codecs

    codecs = store_codecs()
    with new_store(path, "this simulation", "run it again to resume") as g:
        names = subject.all_sequences()
        for name in names:
            key = attrs["keys"][name]
            T = subject.n_frames(name)
            g.create_array(f"{key}/positions", shape=(T, subject.n_vertices, 3),
                           chunks=(min(T, CHUNK_FRAMES), subject.n_vertices, 3), dtype="float32", fill_value=0,
                           **codecs)
            if subject.body is not None:
                a = subject.body.feature_width
                g.create_array(f"{key}/body_features", shape=(T, a), chunks=(T, a), dtype="float32", fill_value=0,
                               **codecs)
        g.create_array("done", shape=(len(names),), chunks=(1,), dtype=bool, fill_value=False, **codecs)
        g.attrs.update(attrs)


def open_store(cfg: RunConfig, subject: ClothSubject, path: Path) -> Any:
    """The cache's zarr group for writing: created when missing, else checked against the config (a cache of
    another configuration is a one-line :class:`PrtError`, nothing written)."""
    import mujoco
    import zarr

    from prt_torch.rundir import stage_key

    key = simulation_key(cfg, subject)
    h = stage_key(key)
    names = subject.all_sequences()
    if not path.exists():
        attrs = {"format": FORMAT, "config_hash": h, "simulation": key, "sequences": names, "splits": subject.splits,
                 "keys": {n: f"s{i:03d}" for i, n in enumerate(names)},
                 "frames": {n: subject.n_frames(n) for n in names}, "n_vertices": subject.n_vertices,
                 "cloth_start": subject.cloth_slice.start, "cloth_stop": subject.cloth_slice.stop,
                 "fps": subject.fps, "timestep": 1.0 / (subject.fps * subject.cloth.substeps),
                 "scene": subject.cloth.scene, "library": {"mujoco": mujoco.__version__}}
        _create_store(path, subject, attrs)
    cache = VertexCache(path)  # checks the format
    if cache.config_hash != h:
        old = cache.attrs.get("simulation", {})
        diff = next((f"{k}" for k in sorted(set(old) | set(key)) if old.get(k) != key.get(k)), "?")
        if diff == "cloth":
            diff = "cloth." + next((k for k in sorted(set(old["cloth"]) | set(key["cloth"]))
                                    if old["cloth"].get(k) != key["cloth"].get(k)), "?")
        raise PrtError(f"{path} was simulated with another configuration ({diff} differs); nothing written: move it "
                       f"away or delete it to simulate again")
    from prt_torch.bake.store import remove_partial_files

    remove_partial_files(path)
    return zarr.open_group(str(path), mode="r+")


def simulate(cfg: RunConfig, progress: bool = True, subject: ClothSubject | None = None,
             workers: int | None = None) -> Path:
    """Simulate every sequence of the run that its vertex cache ``RunDir(cfg.out_dir).simulation`` lacks; returns
    the cache path. Resumable and deterministic (module docstring). ``workers`` (default ``cloth.workers``; 0 =
    one per core): sequences simulated in parallel processes, each with its own MuJoCo model (a sequence's
    numbers do not depend on where it runs); this process writes every result."""
    import os

    from prt_torch.bake.store import writable
    from prt_torch.rundir import RunDir

    subject = ClothSubject.load(cfg) if subject is None else subject
    path = RunDir(cfg.out_dir).simulation
    g = open_store(cfg, subject, path)
    names = subject.all_sequences()
    done = np.asarray(g["done"][...], dtype=bool)
    todo = [names[i] for i in range(len(names)) if not done[i]]
    if not todo:
        return path
    keys = g.attrs["keys"]
    n = subject.cloth.workers if workers is None else workers
    n = min(len(todo), n if n > 0 else (os.cpu_count() or 1))

    def write(res: SequenceResult) -> None:
        writable(g[f"{keys[res.name]}/positions"])[...] = res.positions
        if res.body_features is not None:
            writable(g[f"{keys[res.name]}/body_features"])[...] = res.body_features
        writable(g["done"])[names.index(res.name)] = True

    with _progress(progress) as bar:
        if n <= 1:
            from prt_torch.cloth.engine import Engine

            engine = Engine(subject)
            for name in todo:
                total = subject.cloth.settle_frames + subject.n_frames(name)
                task = bar.add_task(f"simulate {name}", total=total) if bar is not None else None

                def on_frame(k: int, t: int, task: Any = task) -> None:
                    if bar is not None:
                        bar.update(task, completed=k)

                write(simulate_sequence(subject, name, engine, on_frame))
            return path
        import concurrent.futures as cf
        import multiprocessing as mp

        task = bar.add_task(f"simulate {len(todo)} sequences ({n} workers)", total=len(todo)) if bar else None
        with cf.ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                                    initargs=(cfg.model_dump(mode="json"), cfg.base_dir)) as pool:
            futures = {pool.submit(_worker_run, name): name for name in todo}
            for k, fut in enumerate(cf.as_completed(futures)):
                write(fut.result())
                if bar is not None:
                    bar.update(task, completed=k + 1)
    return path


_WORKER: dict[str, Any] = {}


def _worker_init(cfg_json: dict[str, Any], base_dir: Path | None) -> None:
    from prt_torch.cloth.engine import Engine
    from prt_torch.config import config_from_dict

    cfg = config_from_dict(cfg_json, base_dir=base_dir)
    subject = ClothSubject.load(cfg)
    _WORKER.update(subject=subject, engine=Engine(subject))


def _worker_run(name: str) -> SequenceResult:
    return simulate_sequence(_WORKER["subject"], name, _WORKER["engine"])


class _NoBar:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def _progress(enabled: bool) -> Any:
    if not enabled:
        return _NoBar()
    from prt_torch.progress import progress_bar

    return progress_bar(elapsed=False, remaining=True)
