"""A Dask bake that loses a worker mid-bake: ``prt bake --scheduler`` on a real ``distributed.LocalCluster`` of two
worker processes (each under a nanny), one of them SIGKILLed by a scheduler plugin the moment it reports its first
finished block, still finishes, and its store equals an in-process bake bitwise on every array.

The trigger is deterministic, not a sleep: the plugin runs inside the scheduler's own transition of a task to
``memory``, so the kill happens once exactly one block is done, with the killed worker's result held only in its
memory and (two task slots per worker) its next block in flight. Both must be recomputed elsewhere. With no retry
allowed (``distributed.scheduler.allowed-failures = 0``) the same kill fails the bake with one ``error:`` line, and
a resume finishes it. A dead writer's ``*.partial`` chunk file is removed when the bake completes.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from prt_torch.bake.runner import bake
from prt_torch.bake.store import BakedDataset
from prt_torch.config import config_from_dict
from tests.bake.test_concurrency import alive, wait_gone
from tests.bake.test_runner import tiny_config

distributed = pytest.importorskip("distributed")

#: seconds the whole ``prt bake`` subprocess may take (it bakes in a few seconds)
BAKE_TIMEOUT = 240


class KillFirstFinisher(distributed.diagnostics.plugin.SchedulerPlugin):
    """SIGKILL the worker process that finishes the first ``bake_block`` task, from inside that transition; then
    record where every task finished and which workers the scheduler removed."""

    def __init__(self, scheduler: Any) -> None:
        self.scheduler = scheduler
        self.killed: tuple[str, int] | None = None  # (address, pid)
        self.in_flight: set[str] = set()  # keys processing on the killed worker at the kill
        self.first_key: str | None = None
        self.finished_on: dict[str, str] = {}  # key -> worker address of its last transition to memory
        self.removed: list[str] = []

    def transition(self, key: Any, start: str, finish: str, *args: Any, stimulus_id: str, **kwargs: Any) -> None:
        if finish != "memory" or not str(key).startswith("bake_block-"):
            return
        worker = str(kwargs.get("worker", ""))
        self.finished_on[str(key)] = worker
        if self.killed is None and worker in self.scheduler.workers:
            ws = self.scheduler.workers[worker]
            self.in_flight = {str(ts.key) for ts in ws.processing}
            self.first_key = str(key)
            self.killed = (worker, int(ws.pid))
            os.kill(ws.pid, signal.SIGKILL)

    def remove_worker(self, scheduler: Any, worker: str, **kwargs: Any) -> None:
        self.removed.append(worker)


def read_every_array(path: Path) -> dict[str, np.ndarray]:
    g = zarr.open_group(str(path), mode="r")
    return {name: np.asarray(a[:]) for name, a in g.arrays()}


def soak_config() -> dict:
    """The tiny config with 1024 rays and 41 frames: 11 blocks of 4 frames, ~0.3 s each."""
    cfg = tiny_config(Path("unused"), n_rays=1024)
    cfg["character"]["random_poses"] = 30
    return cfg


@pytest.fixture(scope="module")
def local_bake(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference: the same config baked in this process."""
    run_dir = tmp_path_factory.mktemp("local")
    return bake(config_from_dict({**soak_config(), "run_dir": str(run_dir)}), workers=1, progress=False)


async def _add_plugin(scheduler: Any, plugin: Any) -> None:
    """Register ``plugin`` on the scheduler's own event loop (its state is not thread-safe)."""
    scheduler.add_plugin(plugin)


def bake_on_cluster(tmp_path: Path, allowed_failures: int) -> tuple[subprocess.CompletedProcess, KillFirstFinisher]:
    """``prt bake --scheduler`` (a subprocess) on a fresh two-process LocalCluster whose scheduler runs
    :class:`KillFirstFinisher` and allows ``allowed_failures`` worker deaths per task; the cluster is closed after."""
    import dask
    from distributed import Client, LocalCluster

    cfg_path = tmp_path / "cfg.json"
    cfg_path.write_text(json.dumps(soak_config()))
    # two task slots per one-thread worker: a worker that finishes its first block already holds its next one
    with dask.config.set({"distributed.scheduler.worker-saturation": 2.0,
                          "distributed.scheduler.allowed-failures": allowed_failures}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, protocol="tcp://", memory_limit=0,
                               local_directory=str(tmp_path / "dask-scratch"))
    proc = None
    try:
        assert cluster.scheduler.allowed_failures == allowed_failures
        with Client(cluster, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        pids = {ws.pid for ws in cluster.scheduler.workers.values()}
        assert len(pids) == 2 and os.getpid() not in pids  # two worker processes, not threads of this one
        plugin = KillFirstFinisher(cluster.scheduler)
        cluster.sync(_add_plugin, cluster.scheduler, plugin)
        proc = subprocess.Popen([sys.executable, "-m", "prt_torch.cli", "bake", str(cfg_path), "--run-dir",
                                 str(tmp_path / "run"), "--scheduler", cluster.scheduler_address, "--no-progress",
                                 "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = proc.communicate(timeout=BAKE_TIMEOUT)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        cluster.close(timeout=30)
    assert plugin.killed is not None, "no block finished on the cluster: nothing was killed"
    _, pid = plugin.killed
    assert not wait_gone([pid], 10.0), f"the killed worker {pid} still runs"
    assert plugin.in_flight, "the killed worker held no block in flight"
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err), plugin


def assert_equal_stores(path: Path, reference: Path) -> None:
    """Every array of the two stores equal bit for bit: every block traces the same seeded rays with the same
    single-threaded operations, whichever process bakes it (prt_torch.bake.runner)."""
    want, got = read_every_array(reference), read_every_array(path)
    assert sorted(got) == sorted(want) and "visibility" in got and "done" in got
    for name in want:
        a, b = got[name], want[name]
        assert a.dtype == b.dtype and a.shape == b.shape, (name, a.dtype, a.shape, b.dtype, b.shape)
        assert a.tobytes() == b.tobytes(), f"{name}: {np.count_nonzero(a != b)} of {a.size} values differ"


def test_dask_bake_with_a_worker_killed_midway_equals_in_process_bake(tmp_path: Path, local_bake: Path) -> None:
    res, plugin = bake_on_cluster(tmp_path, allowed_failures=3)
    assert res.returncode == 0, res.stderr[-3000:]
    address, pid = plugin.killed
    assert not alive(pid)
    assert address in plugin.removed, "the scheduler never noticed the killed worker"
    # the block whose result lived only in the dead worker's memory, and the one it was baking, finished elsewhere
    for key in {plugin.first_key, *plugin.in_flight}:
        assert key in plugin.finished_on and plugin.finished_on[key] != address, key
    summary = json.loads(res.stdout)
    n = BakedDataset(local_bake).n_frames
    assert summary["frames"] == n and summary["skipped"] == 0
    ds = BakedDataset(tmp_path / "run" / "dataset.zarr")
    assert ds.complete and ds.verify(checksums=True).ok
    assert not list(ds.path.rglob("*.partial")), "a killed worker's partial chunk writes were left in the store"
    assert_equal_stores(ds.path, local_bake)


def test_dask_bake_out_of_retries_is_one_line_error_and_resumes(tmp_path: Path, local_bake: Path) -> None:
    """No retry allowed: the block in flight on the killed worker fails the bake with one ``error:`` line (exit 2,
    no traceback; distributed's own warnings may precede it); the blocks done are kept, and a local resume bakes
    only the rest, equal to the reference."""
    res, plugin = bake_on_cluster(tmp_path, allowed_failures=0)
    assert res.returncode == 2, res.stderr[-3000:]
    lines = res.stderr.strip().splitlines()  # distributed's client may log a warning line before it
    err = lines[-1]
    assert "Traceback" not in res.stderr and sum(x.startswith("error:") for x in lines) == 1, res.stderr
    assert err.startswith("error: Dask workers died 1 time(s) baking frames "), err
    assert "allowed-failures = 0" in err and "run prt bake again to resume" in err
    from prt_torch.bake.runner import run_bake

    resumed = run_bake(config_from_dict({**soak_config(), "run_dir": str(tmp_path / "run")}), workers=1,
                       progress=False)
    assert resumed.skipped >= 4 and resumed.frames + resumed.skipped == BakedDataset(local_bake).n_frames
    assert_equal_stores(resumed.path, local_bake)



def test_partial_chunk_write_of_a_dead_writer_is_removed_when_the_bake_completes(tmp_path: Path) -> None:
    """What a worker SIGKILLed inside zarr's atomic chunk write leaves (a ``<chunk>.<uuid>.partial``, made here after
    the first block, as it appears mid-bake) is gone once the bake completes; the data are untouched by it."""
    from prt_torch.bake.runner import run_bake

    cfg = tiny_config(tmp_path / "run")
    cfg["character"].update(random_poses=8, heldout_clips=[])
    planted: list[Path] = []

    def plant(_stats: object) -> None:
        if not planted:
            chunk = next((tmp_path / "run" / "dataset.zarr" / "visibility" / "c").rglob("*"))
            while chunk.is_dir():
                chunk = next(chunk.iterdir())
            stray = chunk.with_suffix(".0123456789abcdef.partial")
            stray.write_bytes(chunk.read_bytes()[:10])
            planted.append(stray)

    res = run_bake(config_from_dict(cfg), workers=1, progress=False, on_block=plant)
    assert planted and res.frames == 8
    assert not planted[0].exists() and not list(res.path.rglob("*.partial"))
    assert BakedDataset(res.path).verify(checksums=True).ok
