"""The run directory ``runs/NAME/``: the one owner of every file name in it (docs/DESIGN.md).

No other module spells a run-directory file name; they ask a :class:`RunDir`::

    run = RunDir("runs/demo")
    ds = run.dataset()                  # BakedDataset: the only dataset reader
    held = ds.split("heldout")          # SplitData of the done held-out frames
    model = run.model("mlp")            # VisibilityModel (torch), run.model() = the default kind
    meta = run.export_meta()            # export.json (PrtError naming `prt export` when missing)
    if run.is_current("export", key): ...  # one up-to-date key per stage, in stages.json

Layout (written by):

========================================  =========================================================
``dataset.zarr/``, ``character.npz``       ``prt bake`` (the store, the character)
``models/<kind>.pt``, ``model.pt``,        ``prt train`` (one file per kind, the default kind's hard link,
``model.json``, ``metrics.json``,          metadata, training metrics; the learned peak blockers with
``peak_blockers.npz``                      ``train.peaks``)
``report/``                                ``prt eval`` (``index.md``, ``index.html``, ``results.json``, plots)
``visibility.onnx``, ``shading.onnx``,     ``prt export`` (graphs, RPO catalogue, vertex-frame data,
``fused.onnx``, ``rpo/<name>.npz``,        metadata)
``frames.npz``, ``export.json``,
``blockers.npz``, ``peaks.onnx``,          (the blocker spheres; with learned peak blockers, the peak
``fused_peaks.onnx``                       visibility graph and the fused graph with the peak term)
``compare/``                               ``prt compare`` (``table.md``, ``index.html``, ``compare.json``,
                                           ``strip.png``, ``psnr_vs_ms.png``, ``<kind>.visibility.onnx``)
``heldout.mp4``, ``comparison.png``,       ``prt demo`` / ``prt play``
``demo_metrics.json``, ``*.timings.json``,
``play_timings.json``
``stages.json``                            every stage: its up-to-date key (``bake``, ``train``, ``export``)
``.prt.lock``, ``.prt.lock.json``          :meth:`RunDir.lock` (``prt bake``): the lock file and its holder
========================================  =========================================================

Loading methods import their owners lazily (``bake.store``, ``rig.character``, ``models``), so that
this module stays at the bottom of the layers and the player can use it without torch.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import socket
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from prt_torch.errors import DamagedArtifact, MissingArtifact, PrtError, StaleArtifact, check, warn
from prt_torch.io import atomic_write_json, remove_stale_temporaries

if TYPE_CHECKING:
    from prt_torch.bake.store import BakedDataset
    from prt_torch.models.visibility import VisibilityModel
    from prt_torch.rig.character import Character

#: pipeline stages with an up-to-date key in ``stages.json``
STAGES = ("bake", "train", "export")
#: the ONNX graphs of an export, by role
GRAPHS = ("visibility", "shading", "fused")
#: the graphs an export ships for some runs only (``fused_peaks``: a run with learned peak blockers; ``latent``: the
#: pose -> reduced-output graph of the compiled frame path, a model with per-cluster output bases)
OPTIONAL_GRAPHS = ("fused_peaks", "latent")

_DATASET = "dataset.zarr"
_CHARACTER = "character.npz"
_SIMULATION = "simulation.zarr"  # a cloth run's vertex cache (prt_torch.cloth.simulate)
_MODELS = "models"
_DEFAULT_MODEL = "model.pt"
_MODEL_JSON = "model.json"
_METRICS_JSON = "metrics.json"
_TRANSFER_JSON = "transfer.json"  # learned transfer (seed 000): metadata + sha256 of models/<array>_<kind>.pt
_REPORT = "report"
_RESULTS_JSON = "results.json"
_EXPORT_JSON = "export.json"
_FRAMES = "frames.npz"
_DECODE = "decode.npz"  # the compiled frame path's per-cluster output bases (prt_torch.export.compiled)
_BLOCKERS = "blockers.npz"
_PEAK_BLOCKERS = "peak_blockers.npz"
_PEAKS_ONNX = "peaks.onnx"
_SHEXP_ONNX = "shexp.onnx"
_TRANSFER_ONNX = "transfer.onnx"  # the learned transfer graph (prt_torch.transfer.graph)
_S001 = "s001.npz"
_DEFORM = "deform.npz"  # a deformable run's frame operator + cloth edges (prt_torch.cloth.export)
_POSITIONS_ONNX = "positions.onnx"  # a deformable run's positions-in visibility graph
_POSITIONS_FUSED_ONNX = "positions_fused.onnx"  # a deformable run's positions-in radiance graph (cluster order)
_LOCAL_ONNX = "local.onnx"  # a deformable run's shipped local visibility network (prt_torch.local.graph)
_LOCAL_DATA = "local.npz"  # its neighbour indices
_RPO = "rpo"
_MATERIAL_RPO = "material"  # rpo/material-<key>.npz: the character material's RPO (player cache)
_COMPARE = "compare"
_COMPARE_JSON = "compare.json"
_COMPARE_TABLE = "table.md"
_INDEX_HTML = "index.html"
_INDEX_MD = "index.md"
_COMPARE_STRIP = "strip.png"
_COMPARE_SCATTER = "psnr_vs_ms.png"
_COMPARE_GRAPH_SUFFIX = ".visibility.onnx"
_STAGES = "stages.json"
_DEMO_VIDEO = "heldout.mp4"
_DEMO_IMAGE = "comparison.png"
_DEMO_METRICS = "demo_metrics.json"
_PLAY_TIMINGS = "play_timings.json"
_SCENE_JSON = "scene.json"
_COMPARE_GROUND = "ground.png"
_LOCK = ".prt.lock"
_LOCK_INFO = ".prt.lock.json"


def stage_key(obj: Any) -> str:
    """sha256 of ``obj`` as canonical JSON (sorted keys; paths and other objects by ``str``)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def file_sha256(path: str | os.PathLike[str]) -> str:
    """sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


_SHA256 = re.compile(r"[0-9a-f]{64}")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


class _Hasher:
    """sha256 of files, each inode hashed once (``model.pt`` is a hard link to a ``models/<kind>.pt``)."""

    def __init__(self) -> None:
        self._seen: dict[tuple[int, int, int, int], str] = {}

    def sha256(self, path: Path) -> str:
        st = path.stat()
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in self._seen:
            self._seen[key] = file_sha256(path)
        return self._seen[key]

    def hashes(self, run: RunDir, paths: Iterable[Path]) -> dict[str, str]:
        return {run.relative(p): self.sha256(Path(p)) for p in paths}


class RunDir:
    """A run directory (it need not exist yet: the bake creates it).

    Args:
        path: ``runs/NAME`` (a ``dataset.zarr`` path is accepted too and means its parent).
    """

    def __init__(self, path: str | os.PathLike[str] | RunDir) -> None:
        p = Path(path.path if isinstance(path, RunDir) else path)
        if p.name == _DATASET:
            p = p.parent
        self.path = p

    @classmethod
    def of(cls, run: str | os.PathLike[str] | RunDir) -> RunDir:
        """``run`` itself when it is a :class:`RunDir`, else a new one."""
        return run if isinstance(run, RunDir) else cls(run)

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    def __truediv__(self, other: str) -> Path:  # pragma: no cover - discouraged: use the named properties
        raise TypeError("RunDir / name: use a named property of RunDir (it owns the file names)")

    def require(self) -> RunDir:
        """``self``; :class:`PrtError` when the directory does not exist."""
        if not self.path.is_dir():
            raise MissingArtifact(f"run directory not found: {self.path}")
        return self

    # -- bake ------------------------------------------------------------------------------------
    @property
    def dataset_path(self) -> Path:
        """``dataset.zarr/``: the baked store (``prt_torch.bake.store``)."""
        return self.path / _DATASET

    @property
    def character_path(self) -> Path:
        """``character.npz``: the baked character."""
        return self.path / _CHARACTER

    @property
    def simulation(self) -> Path:
        """``simulation.zarr/``: a cloth run's vertex cache (``prt simulate``, :mod:`prt_torch.cloth.simulate`)."""
        return self.path / _SIMULATION

    def dataset(self) -> BakedDataset:
        """The baked dataset (:class:`prt_torch.bake.store.BakedDataset`, the only dataset reader)."""
        from prt_torch.bake.store import BakedDataset

        if not self.dataset_path.exists():
            raise MissingArtifact(f"no dataset in {self.path} ({_DATASET} missing): run `prt bake CONFIG` first")
        return BakedDataset(self.dataset_path)

    def resolve_dataset(self, meta: dict[str, Any], dataset: str | os.PathLike[str] | None = None) -> BakedDataset:
        """The dataset a trained run is scored on (``prt eval``, ``prt compare``): ``dataset`` when given, else the
        run's own, else the one recorded in ``model.json`` at training time (``meta["dataset"]``; one warning line
        names it: it is not the run's own). ``meta``: :meth:`model_meta`. A dataset of another character than the
        model's (``meta["character_hash"]``, ``meta["n_vertices"]``) is a :class:`PrtError`; none found, a
        :class:`MissingArtifact`."""
        from prt_torch.bake.store import open_dataset

        if dataset is not None:
            ds = open_dataset(dataset)
        elif self.dataset_path.exists():
            ds = self.dataset()
        else:
            recorded = Path(str(meta.get("dataset", "")))
            if not (str(meta.get("dataset", "")) and recorded.exists()):
                raise MissingArtifact(f"dataset not found for {self.path} (recorded {recorded}): pass --dataset")
            ds = open_dataset(recorded)
            warn(f"{self.dataset_path} not found: reading the dataset recorded at training time, {ds.path}")
        want = str(meta.get("character_hash") or "")
        check(not want or ds.character_hash == want,
              f"{ds.path} was baked from another character (hash {ds.character_hash[:12]}) than the model of "
              f"{self.path} ({want[:12]})")
        check(ds.n_vertices == int(meta["n_vertices"]),
              f"{ds.path} has {ds.n_vertices} vertices, the model of {self.path} {meta['n_vertices']}")
        return ds

    def character(self, expect_hash: str | None = None) -> Character:
        """The run's character; ``expect_hash``: its content hash must equal this."""
        from prt_torch.rig.character import Character

        if not self.character_path.is_file():
            raise MissingArtifact(f"no character in {self.path} ({_CHARACTER} missing): run `prt bake CONFIG` first")
        ch = Character.load(self.character_path)
        if expect_hash:
            h = ch.content_hash()
            if h != expect_hash:
                raise StaleArtifact(f"{self.character_path} (hash {h[:12]}) is not the character this run was "
                                    f"made for ({expect_hash[:12]})")
        return ch

    # -- train -----------------------------------------------------------------------------------
    @property
    def models_dir(self) -> Path:
        return self.path / _MODELS

    def model_path(self, kind: str | None = None) -> Path:
        """``model.pt`` (the default kind) for ``kind=None``, else ``models/<kind>.pt``."""
        if kind is None:
            return self.path / _DEFAULT_MODEL
        check(bool(kind) and "/" not in kind and kind[0] != ".", f"bad model kind {kind!r}")
        return self.models_dir / f"{kind}.pt"

    @property
    def model_json(self) -> Path:
        return self.path / _MODEL_JSON

    @property
    def metrics_json(self) -> Path:
        return self.path / _METRICS_JSON

    def transfer_model_path(self, kind: str, array: str = "transfer") -> Path:
        """``models/<array>_<kind>.pt``: a learned transfer model (``array``: ``transfer`` or ``subsurface``)."""
        check(array.isidentifier() and kind.isidentifier(), f"bad transfer model {array!r} / {kind!r}")
        return self.models_dir / f"{array}_{kind}.pt"

    def local_model_path(self, kind: str) -> Path:
        """``models/local_<kind>.pt``: a local visibility model (``prt train`` with ``train.local``,
        :mod:`prt_torch.local.fit`)."""
        check(kind.isidentifier(), f"bad local model kind {kind!r}")
        return self.models_dir / f"local_{kind}.pt"

    @property
    def transfer_json(self) -> Path:
        return self.path / _TRANSFER_JSON

    def transfer_meta(self) -> dict[str, Any]:
        """``transfer.json`` (written by ``prt train`` with ``train.transfer``), every model file it lists verified."""
        path = self.transfer_json
        if not path.is_file():
            raise MissingArtifact(f"no learned transfer in {self.path} (train with a `train.transfer` section)")
        meta = self._read_unit(path, "train")
        self._verify_files(path, "train", meta.get("files"), [])
        return meta

    def model(self, kind: str | None = None) -> VisibilityModel:
        """The trained model of ``kind`` (``None``: the default one). Needs torch."""
        from prt_torch.models.visibility import load_model

        return load_model(self, kind)

    def model_meta(self) -> dict[str, Any]:
        """``model.json``: conventions, dimensions, kinds, chosen hyper-parameters."""
        if not self.model_json.is_file():
            raise MissingArtifact(f"model metadata not found: {self.model_json} (run `prt train CONFIG` first)")
        return self.verify_model_meta(self._read_unit(self.model_json, "train"))

    # -- eval / compare ----------------------------------------------------------------------------
    @property
    def report_dir(self) -> Path:
        return self.path / _REPORT

    @property
    def report_json(self) -> Path:
        """``report/results.json``: the ``prt eval`` results."""
        return self.report_dir / _RESULTS_JSON

    @property
    def report_index_md(self) -> Path:
        """``report/index.md``: the ``prt eval`` report (its figures beside it are named by ``eval.report``)."""
        return self.report_dir / _INDEX_MD

    @property
    def report_index_html(self) -> Path:
        """``report/index.html``: the same report as HTML."""
        return self.report_dir / _INDEX_HTML

    @property
    def compare_dir(self) -> Path:
        return self.path / _COMPARE

    @property
    def compare_json(self) -> Path:
        """``compare/compare.json``: every method's figures (schema in :mod:`prt_torch.compare`)."""
        return self.compare_dir / _COMPARE_JSON

    @property
    def compare_table(self) -> Path:
        """``compare/table.md``: the same as a Markdown table."""
        return self.compare_dir / _COMPARE_TABLE

    @property
    def compare_html(self) -> Path:
        """``compare/index.html``: table and figures."""
        return self.compare_dir / _INDEX_HTML

    @property
    def compare_strip(self) -> Path:
        """``compare/strip.png``: truth | each method | 4x difference, at the frame with the most shadowing."""
        return self.compare_dir / _COMPARE_STRIP

    @property
    def compare_scatter(self) -> Path:
        """``compare/psnr_vs_ms.png``: image PSNR vs milliseconds per frame."""
        return self.compare_dir / _COMPARE_SCATTER

    def compare_graph_path(self, kind: str) -> Path:
        """``compare/<kind>.visibility.onnx``: a kind's visibility graph exported by ``prt compare``."""
        check(bool(kind) and "/" not in kind and kind[0] != ".", f"bad model kind {kind!r}")
        return self.compare_dir / f"{kind}{_COMPARE_GRAPH_SUFFIX}"

    # -- export ----------------------------------------------------------------------------------
    @property
    def export_json(self) -> Path:
        return self.path / _EXPORT_JSON

    @property
    def frames_path(self) -> Path:
        """``frames.npz``: cluster labels / axes / bones for the player's vertex frames."""
        return self.path / _FRAMES

    @property
    def decode_path(self) -> Path:
        """``decode.npz``: the per-cluster output bases of the compiled frame path, as the fused graph holds them
        (:mod:`prt_torch.export.compiled`, ``prt export`` of a model with per-cluster bases)."""
        return self.path / _DECODE

    @property
    def latent_graph_path(self) -> Path:
        """``latent.onnx``: ``pose (B, A) -> z (B, G, K)``, the model up to its output bases (the compiled frame
        path's first step, :mod:`prt_torch.export.compiled`)."""
        return self.graph_path("latent")

    @property
    def rpo_dir(self) -> Path:
        return self.path / _RPO

    @property
    def blockers_path(self) -> Path:
        """``blockers.npz``: the character's sphere blockers (:class:`prt_torch.blockers.SphereSet`), ``prt export``."""
        return self.path / _BLOCKERS

    @property
    def peak_blockers_path(self) -> Path:
        """``peak_blockers.npz``: the learned peak blockers (a :class:`prt_torch.blockers.SphereSet` fitted to the
        bake's peak visibility, :mod:`prt_torch.fit.peaks`; ``prt train`` of a dataset baked with ``bake.peaks``)."""
        return self.path / _PEAK_BLOCKERS

    @property
    def peak_graph_path(self) -> Path:
        """``peaks.onnx``: the learned peak-visibility graph (:mod:`prt_torch.export.peaks_graph`, ``prt export``)."""
        return self.path / _PEAKS_ONNX

    @property
    def fused_peaks_graph_path(self) -> Path:
        """``fused_peaks.onnx``: the fused graph with the peak lights' term, learned shadows included
        (:class:`prt_torch.export.peaks_graph.FusedPeaksGraph`, ``prt export`` of a run with learned peak blockers)."""
        return self.graph_path("fused_peaks")

    @property
    def s001(self) -> Path:
        """``s001.npz``: seed 001's compressed transfer matrices (``prt train`` with ``train.s001``)."""
        return self.path / _S001

    @property
    def shexp_path(self) -> Path:
        """``shexp.onnx``: the SHEXP sphere-blocker visibility graph (:mod:`prt_torch.shexp.graph`)."""
        return self.path / _SHEXP_ONNX

    @property
    def deform_path(self) -> Path:
        """``deform.npz``: a deformable run's frame operator, cloth edges and layout (``prt export``)."""
        return self.path / _DEFORM

    @property
    def local_graph_path(self) -> Path:
        """``local.onnx``: the shipped local visibility network (``train.local.default``,
        :mod:`prt_torch.local.graph`)."""
        return self.path / _LOCAL_ONNX

    @property
    def local_data_path(self) -> Path:
        """``local.npz``: the shipped local model's neighbour indices (:mod:`prt_torch.local.graph`)."""
        return self.path / _LOCAL_DATA

    @property
    def positions_graph_path(self) -> Path:
        """``positions.onnx``: a deformable run's ``positions (B, V, 3) -> visibility`` graph (``prt export``)."""
        return self.path / _POSITIONS_ONNX

    @property
    def positions_fused_path(self) -> Path:
        """``positions_fused.onnx``: a deformable run's ``positions -> radiance`` graph (``prt export``)."""
        return self.path / _POSITIONS_FUSED_ONNX

    @property
    def transfer_graph_path(self) -> Path:
        """``transfer.onnx``: the learned transfer graph ``(pose, light) -> (transfer, L . t [, subsurface, ...])``
        (:mod:`prt_torch.transfer.graph`, ``prt export`` of a run with ``transfer.json``)."""
        return self.path / _TRANSFER_ONNX

    def graph_path(self, graph: str) -> Path:
        """``<graph>.onnx`` for ``graph`` in :data:`GRAPHS` or :data:`OPTIONAL_GRAPHS`."""
        check(graph in GRAPHS + OPTIONAL_GRAPHS, f"unknown graph {graph!r}: expected one of "
                                                 f"{list(GRAPHS + OPTIONAL_GRAPHS)}")
        return self.path / f"{graph}.onnx"

    def rpo_path(self, name: str) -> Path:
        """``rpo/<name>.npz``."""
        check(bool(name) and "/" not in name and not name.startswith("."), f"bad BRDF name {name!r}")
        return self.rpo_dir / f"{name}.npz"

    def material_rpo_path(self, key: str) -> Path:
        """``rpo/material-<key>.npz``: the character material's RPO, content-addressed (``key``: hex digest of its
        BRDF and settings, :func:`prt_torch.rig.material.material_rpo_key`), built by the player on first use."""
        check(re.fullmatch(r"[0-9a-f]{8,64}", key) is not None, f"bad material RPO key {key!r}")
        return self.rpo_dir / f"{_MATERIAL_RPO}-{key}.npz"

    def relative(self, path: Path) -> str:
        """``path`` relative to the run directory, POSIX style (for metadata files)."""
        return Path(path).relative_to(self.path).as_posix()

    def export_meta(self) -> dict[str, Any]:
        """``export.json``, verified (:meth:`verify_export_meta`); :class:`PrtError` naming ``prt export`` when
        the run is not exported or its export is incomplete."""
        self.require()
        if not self.export_json.is_file():
            raise MissingArtifact(f"{self.path} is not exported ({_EXPORT_JSON} missing): run `prt export "
                                  f"{self.path}` first")
        return self.verify_export_meta(self._read_unit(self.export_json, "export"))

    # -- demo / play -----------------------------------------------------------------------------
    @property
    def demo_video(self) -> Path:
        return self.path / _DEMO_VIDEO

    @property
    def demo_image(self) -> Path:
        return self.path / _DEMO_IMAGE

    @property
    def demo_metrics(self) -> Path:
        return self.path / _DEMO_METRICS

    @property
    def play_timings(self) -> Path:
        """Frame timings of ``prt play`` without an output video."""
        return self.path / _PLAY_TIMINGS

    @property
    def scene_json(self) -> Path:
        """The run's scene (``prt_torch.scene.config.SceneConfig`` as JSON; written by ``prt demo`` from the
        config's ``scene:`` section): read by ``prt play --ground`` and ``prt compare``."""
        return self.path / _SCENE_JSON

    @property
    def compare_ground(self) -> Path:
        """``compare/ground.png``: the ground's cast shadow, SHEXP vs whole-scene Embree truth."""
        return self.compare_dir / _COMPARE_GROUND

    def timings_path(self, video: str | os.PathLike[str]) -> Path:
        """``<video stem>.timings.json`` next to a video (or in the run directory for a bare name)."""
        v = Path(video)
        return v.with_name(f"{v.stem}.timings.json")

    # -- stage keys ------------------------------------------------------------------------------
    @property
    def stages_json(self) -> Path:
        return self.path / _STAGES

    def stage_keys(self) -> dict[str, str]:
        """``{stage: key}`` of the finished stages (empty when none recorded)."""
        if not self.stages_json.is_file():
            return {}
        data = self.read_json(self.stages_json)
        return {k: str(v) for k, v in data.items() if k in STAGES}

    def is_current(self, stage: str, key: str, outputs: tuple[Path, ...] = ()) -> bool:
        """Whether ``stage`` last finished with ``key`` and all its ``outputs`` still exist."""
        check(stage in STAGES, f"unknown stage {stage!r}: expected one of {list(STAGES)}")
        return self.stage_keys().get(stage) == key and all(Path(p).exists() for p in outputs)

    def mark_done(self, stage: str, key: str) -> None:
        """Record that ``stage`` finished with ``key`` (atomically; later stages' keys are kept: each key
        hashes its own inputs, so a stale later stage is recognised by its own key)."""
        check(stage in STAGES, f"unknown stage {stage!r}: expected one of {list(STAGES)}")
        keys = self.stage_keys()
        keys[stage] = key
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.stages_json, keys)

    # -- lock ------------------------------------------------------------------------------------
    @property
    def lock_path(self) -> Path:
        """``.prt.lock``: the run directory's lock file (an OS file lock through ``filelock``)."""
        return self.path / _LOCK

    @property
    def lock_info_path(self) -> Path:
        """``.prt.lock.json``: who holds the lock (pid, host, stage, start time)."""
        return self.path / _LOCK_INFO

    @contextlib.contextmanager
    def lock(self, stage: str, timeout: float = 0) -> Iterator[None]:
        """Hold the run directory's exclusive lock while ``stage`` runs (``prt bake`` holds it for its whole run).

        The lock is ``fcntl.flock`` on :attr:`lock_path` (``filelock``), so the kernel releases it when its
        holder dies, even by SIGKILL; the holder info is written beside it atomically and removed on release.
        Creates the run directory.

        Args:
            stage: what holds the lock (``bake``), named in the error another process gets.
            timeout: seconds to wait for another holder; 0 fails at once.

        Raises:
            PrtError: ``runs/x is locked by prt bake (pid 123 on host, since 12:01:02)``, one line.
        """
        from filelock import FileLock, Timeout

        check(bool(stage) and stage.replace("-", "_").isidentifier(), f"bad stage name {stage!r}")
        self.path.mkdir(parents=True, exist_ok=True)
        lk = FileLock(str(self.lock_path), timeout=timeout)
        try:
            lk.acquire()
        except Timeout:
            raise PrtError(f"{self.path} is locked by {self._lock_holder()}") from None
        try:
            atomic_write_json(self.lock_info_path, {"pid": os.getpid(), "host": socket.gethostname(), "stage": stage,
                                                    "since": time.time()})
            yield
        finally:
            with contextlib.suppress(OSError):
                self.lock_info_path.unlink()
            lk.release()

    def _lock_holder(self, wait: float = 2.0) -> str:
        """``prt bake (pid 123 on host, since 12:01:02)``: the live holder named by the info file; waits up to
        ``wait`` seconds for a holder that has just taken the lock to write it."""
        deadline = time.monotonic() + wait
        host = socket.gethostname()
        while True:
            try:
                info = json.loads(self.lock_info_path.read_text(encoding="utf-8"))
                pid, where, stage, since = int(info["pid"]), str(info["host"]), str(info["stage"]), float(info["since"])
            except (OSError, ValueError, KeyError, TypeError):
                info = None
            if info is not None and (where != host or _pid_alive(pid)):
                t = time.localtime(since)
                fmt = "%H:%M:%S" if t[:3] == time.localtime()[:3] else "%Y-%m-%d %H:%M:%S"
                return f"prt {stage} (pid {pid} on {where}, since {time.strftime(fmt, t)})"
            if time.monotonic() >= deadline:
                return f"another process (see {self.lock_path})"
            time.sleep(0.05)

    # -- committed units (docs/DESIGN.md, failure model) -------------------------------------------
    # A stage writes its files one by one (each atomically), then its metadata file LAST with the sha256 of
    # every file of its unit: model.json (`files`) for train, export.json (`file_sha256`, and the source
    # model's `model_sha256`) for export. The metadata file is the commit record; readers verify it.

    @property
    def artifact_dirs(self) -> tuple[Path, ...]:
        """The directories stages write into (where stale temporaries are looked for)."""
        return (self.path, self.models_dir, self.rpo_dir, self.report_dir, self.compare_dir)

    def begin(self, stage: str, targets: Iterable[Path] = ()) -> list[Path]:
        """Start (re)running ``stage``: first drop its key from ``stages.json`` (so a kill mid-stage never
        leaves the old key claiming the new, partly written files up to date), then delete stale temporaries
        in :attr:`artifact_dirs` (:func:`prt_torch.io.stale_temporaries`: those of the ``targets`` the stage is
        about to write, and those whose writer is gone). Returns the deleted temporaries."""
        check(stage in STAGES, f"unknown stage {stage!r}: expected one of {list(STAGES)}")
        try:
            keys = self.stage_keys()
        except DamagedArtifact:  # a damaged stages.json only means that nothing is known to be up to date
            keys = {stage: ""}
        if stage in keys:
            keys.pop(stage)
            self.path.mkdir(parents=True, exist_ok=True)
            atomic_write_json(self.stages_json, keys)
        return remove_stale_temporaries(self.artifact_dirs, targets)

    def unit_hashes(self, paths: Iterable[Path]) -> dict[str, str]:
        """``{relative path: sha256}`` of ``paths`` (files of the run directory), for a commit record."""
        return _Hasher().hashes(self, paths)

    def _read_unit(self, path: Path, stage: str) -> dict[str, Any]:
        try:
            return self.read_json(path)
        except PrtError as exc:
            raise type(exc)(f"{exc}: {self._rerun(stage)}") from None

    def _rerun(self, stage: str) -> str:
        return "run `prt train CONFIG` again" if stage == "train" else f"run `prt export {self.path}` again"

    def _unit_error(self, path: Path, stage: str, problem: str) -> DamagedArtifact:
        return DamagedArtifact(f"{path}: {problem} (incomplete or damaged {stage} output): {self._rerun(stage)}")

    def _verify_files(self, path: Path, stage: str, hashes: Any, required: Iterable[str]) -> None:
        """Every file of ``hashes`` (``{relative path: sha256}``) exists with that hash; ``required`` are listed."""
        if not (isinstance(hashes, dict) and hashes and all(isinstance(k, str) and isinstance(v, str)
                                                            and _SHA256.fullmatch(v) for k, v in hashes.items())):
            raise self._unit_error(path, stage, "no valid file hashes")
        missing = sorted(set(required) - set(hashes))
        if missing:
            raise self._unit_error(path, stage, f"no hash recorded for {missing[0]}")
        hasher = _Hasher()
        for rel, want in sorted(hashes.items()):
            p = self.inside(rel)
            if p is None:
                raise self._unit_error(path, stage, f"bad file entry {rel!r}")
            if not p.is_file():
                raise self._unit_error(path, stage, f"{rel} is missing")
            if hasher.sha256(p) != want:
                raise self._unit_error(path, stage, f"{rel} is not the file it records (sha256 differs)")

    def inside(self, rel: str) -> Path | None:
        """``rel`` as a path inside the run directory (``None`` when it is absolute or leaves it)."""
        r = Path(rel)
        if not rel or r.is_absolute() or ".." in r.parts:
            return None
        return self.path / r

    def verify_model_meta(self, meta: dict[str, Any]) -> dict[str, Any]:
        """``model.json``'s content checked as the train unit's commit record: its keys and types, and every
        model file (each kind's and the default one) present with the recorded sha256. Returns ``meta``."""
        path, stage = self.model_json, "train"
        kinds = meta.get("kinds")
        if not (isinstance(kinds, list) and kinds and all(isinstance(k, str) and k for k in kinds)):
            raise self._unit_error(path, stage, "missing or bad key 'kinds'")
        if meta.get("default_kind") not in kinds:
            raise self._unit_error(path, stage, "missing or bad key 'default_kind'")
        for key in ("order", "n_coeffs", "n_vertices", "n_features"):
            if not _is_int(meta.get(key)):
                raise self._unit_error(path, stage, f"missing or bad key {key!r}")
        try:
            required = [self.relative(self.model_path(k)) for k in kinds] + [self.relative(self.model_path())]
        except PrtError:
            raise self._unit_error(path, stage, "missing or bad key 'kinds'") from None
        self._verify_files(path, stage, meta.get("files"), required)
        return meta

    def verify_export_meta(self, meta: dict[str, Any]) -> dict[str, Any]:
        """``export.json``'s content checked as the export unit's commit record: its keys and types, and every
        graph, the frame data and every RPO file present with the recorded sha256 (``file_sha256``). Whether
        the model it was exported from is still the run's model is the reader's question (``model_file``,
        ``model_sha256``; the player asks it). Returns ``meta``."""
        path, stage = self.export_json, "export"
        for key in ("sh_order", "n_vertices", "n_features", "n_terms"):
            if not _is_int(meta.get(key)):
                raise self._unit_error(path, stage, f"missing or bad key {key!r}")
        for key in ("character_hash", "frames_file", "model_file", "model_sha256"):
            if not (isinstance(meta.get(key), str) and meta[key]):
                raise self._unit_error(path, stage, f"missing or bad key {key!r}")
        files, rpos = meta.get("files"), meta.get("rpo_files")
        if not (isinstance(files, dict) and set(GRAPHS) <= set(files) and all(isinstance(v, str) for v in
                                                                              files.values())):
            raise self._unit_error(path, stage, "missing or bad key 'files'")
        if not (isinstance(rpos, dict) and rpos and all(isinstance(k, str) and isinstance(v, str)
                                                         for k, v in rpos.items())):
            raise self._unit_error(path, stage, "missing or bad key 'rpo_files'")
        model = self.inside(meta["model_file"])
        if model is None or model.suffix != self.model_path().suffix:
            raise self._unit_error(path, stage, "missing or bad key 'model_file'")
        required = [files[g] for g in GRAPHS] + list(rpos.values()) + [meta["frames_file"]]
        self._verify_files(path, stage, meta.get("file_sha256"), required)
        return meta

    # -- helpers ---------------------------------------------------------------------------------
    @staticmethod
    def read_json(path: Path) -> dict[str, Any]:
        """A JSON object file; one-line :class:`PrtError` when it is unreadable or not an object."""
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise MissingArtifact(f"file not found: {path}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise DamagedArtifact(f"{path}: not valid JSON ({type(exc).__name__})") from None
        if not isinstance(data, dict):
            raise DamagedArtifact(f"{path}: expected a JSON object")
        return data
