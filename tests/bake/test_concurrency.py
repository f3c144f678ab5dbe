"""Concurrency and process hygiene of the bake: the run-directory lock, atomic store creation, pool workers
that die with their parent.

* Two ``prt bake`` of one config started together (separate subprocesses, ``RACE_TRIALS`` times): exactly
  one wins, the other exits 2 with one ``error:`` line naming the winner's pid, and the store verifies.
* A bake started while another holds the lock fails at once naming the holder; the lock dies with its holder.
* Store creation never replaces an existing store; stale temporary stores are removed by the lock holder.
* SIGKILL of the parent of a ``--workers 2`` bake: its pool workers are gone within seconds (Linux: the
  kernel's parent-death signal; elsewhere, and tested here too, a watchdog thread polling the parent pid).
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr

from prt_torch.bake.runner import run_bake
from prt_torch.bake.store import BakedDataset, _rename_noreplace, create_store
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.rundir import RunDir
from tests.bake.test_runner import tiny_config

#: how many times two bakes race on one config
RACE_TRIALS = 3
LOCKED = r"is locked by prt bake \(pid {pid} on {host}, since \d\d:\d\d:\d\d\)"


def prt_bake(cfg: Path, run_dir: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "prt_torch.cli", "bake", str(cfg), "--run-dir", str(run_dir),
                             "--no-progress", "--json", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def write_config(tmp_path: Path, **character: object) -> Path:
    """The tiny config with 512 rays (a bake of a few seconds), as JSON."""
    cfg = tiny_config(tmp_path / "unused", n_rays=512)
    cfg["character"].update(character)
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(cfg))
    return path


def test_two_bakes_race_one_wins_and_the_store_verifies(tmp_path: Path) -> None:
    cfg = write_config(tmp_path)
    for trial in range(RACE_TRIALS):
        run_dir = tmp_path / f"race{trial}"
        procs = [prt_bake(cfg, run_dir, "--workers", "1") for _ in range(2)]
        outs = [p.communicate(timeout=300) for p in procs]
        codes = sorted(p.returncode for p in procs)
        assert codes == [0, 2], (trial, codes, [o[1][-2000:] for o in outs])
        win = [p.returncode for p in procs].index(0)
        err = outs[1 - win][1]
        assert err.count("\n") == 1 and err.startswith("error: "), err
        assert re.search(LOCKED.format(pid=procs[win].pid, host=re.escape(socket.gethostname())), err), err
        assert str(run_dir) in err
        ds = BakedDataset(run_dir / "dataset.zarr")
        assert ds.complete and ds.verify(checksums=True).ok
        assert json.loads(outs[win][0])["frames"] == ds.n_frames
        assert not list(run_dir.glob(".dataset.zarr.tmp-*")) and not RunDir(run_dir).lock_info_path.exists()


def test_locked_run_directory_fails_at_once_naming_the_holder(tmp_path: Path) -> None:
    cfg = config_from_dict(tiny_config(tmp_path / "run"))
    run = RunDir(tmp_path / "run")
    with run.lock("bake"):
        info = json.loads(run.lock_info_path.read_text())
        assert info["pid"] == os.getpid() and info["stage"] == "bake" and info["host"] == socket.gethostname()
        t0 = time.monotonic()
        with pytest.raises(PrtError, match=LOCKED.format(pid=os.getpid(), host=socket.gethostname())):
            run_bake(cfg, workers=1, progress=False)
        assert time.monotonic() - t0 < 5
        cli = write_config(tmp_path)
        out = prt_bake(cli, tmp_path / "run", "--workers", "1")
        _, err = out.communicate(timeout=120)
        assert out.returncode == 2 and err.count("\n") == 1, err
        assert err.startswith(f"error: {tmp_path / 'run'} is locked by prt bake (pid {os.getpid()} on ")
    assert not run.lock_info_path.exists()
    assert not (tmp_path / "run" / "dataset.zarr").exists()  # the refused bakes wrote nothing


def test_lock_dies_with_its_holder(tmp_path: Path) -> None:
    """A SIGKILLed holder leaves its info file behind; the kernel released the lock, so the next taker wins."""
    run = RunDir(tmp_path / "run")
    code = ("import sys, time; from prt_torch.rundir import RunDir\n"
            "with RunDir(sys.argv[1]).lock('bake'):\n    print('held', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(run.path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(PrtError, match=LOCKED.format(pid=holder.pid, host=socket.gethostname())):
            with run.lock("bake"):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert run.lock_info_path.exists()  # stale
    with run.lock("bake"):
        assert json.loads(run.lock_info_path.read_text())["pid"] == os.getpid()


def test_store_creation_never_replaces_a_store(tmp_path: Path) -> None:
    src, dst = tmp_path / "src", tmp_path / "dst"
    src.mkdir()
    dst.mkdir()
    (dst / "keep").write_text("x")
    with pytest.raises(FileExistsError):
        _rename_noreplace(src, dst)
    (dst / "keep").unlink()
    with pytest.raises(FileExistsError):  # not even an empty directory
        _rename_noreplace(src, dst)
    assert src.is_dir() and dst.is_dir()
    _rename_noreplace(src, tmp_path / "new")
    assert (tmp_path / "new").is_dir() and not src.exists()
    # a store that appears while another is being created is kept, and the loser's temporary store is removed
    path = tmp_path / "run" / "dataset.zarr"
    attrs = {"format_version": 2}

    def appear(src: Path, dst: Path) -> None:
        dst.mkdir()
        (dst / "zarr.json").write_text("{}")
        _rename_noreplace(src, dst)

    import prt_torch.bake.store as store

    real = store._rename_noreplace
    store._rename_noreplace = appear
    try:
        with pytest.raises(PrtError, match="appeared while this bake was creating it"):
            create_store(path, {"pose": np.zeros((4, 2), np.float32)}, {}, 4, 2, attrs)
    finally:
        store._rename_noreplace = real
    assert (path / "zarr.json").read_text() == "{}" and not list(path.parent.glob(".dataset.zarr.tmp-*"))


def test_stale_temporary_store_is_removed_by_the_lock_holder(tmp_path: Path) -> None:
    stale = tmp_path / "run" / ".dataset.zarr.tmp-dead0000"
    zarr.open_group(str(stale), mode="w-", zarr_format=3)
    cfg = tiny_config(tmp_path / "run")
    cfg["character"].update(random_poses=4, heldout_clips=[])
    res = run_bake(config_from_dict(cfg), workers=1, progress=False)
    assert not stale.exists() and BakedDataset(res.path).complete


# -- orphaned workers ------------------------------------------------------------------------------

def children(pid: int) -> dict[int, str]:
    """``{pid: command line}`` of the descendants of ``pid``, from /proc (psutil is not a declared dependency)."""
    out: dict[int, str] = {}
    parents = {pid}
    changed = True
    while changed:
        changed = False
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
                cmd = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except (OSError, IndexError):
                continue
            p = int(stat.parent.name)
            if int(fields[1]) in parents and p not in parents:
                parents.add(p)
                out[p] = cmd
                changed = True
    return out


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie waiting for a reaper does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        return state not in ("Z", "X")
    except (OSError, IndexError):
        if sys.platform.startswith("linux"):
            return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def wait_gone(pids: list[int], seconds: float) -> list[int]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.05)
    return [p for p in pids if alive(p)]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")
def test_pool_workers_die_with_their_parent(tmp_path: Path) -> None:
    cfg = write_config(tmp_path, random_poses=30)
    run_dir = tmp_path / "run"
    proc = prt_bake(cfg, run_dir, "--workers", "2")
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        done_path = run_dir / "dataset.zarr"
        while time.monotonic() < deadline and proc.poll() is None:
            workers = [p for p, cmd in children(proc.pid).items() if "spawn_main" in cmd]
            if len(workers) == 2 and (done_path / "done" / "zarr.json").exists():
                done = np.asarray(zarr.open_group(str(done_path), mode="r")["done"][:])
                if 4 <= done.sum() < len(done):  # the workers are writing blocks
                    break
            time.sleep(0.02)
        else:
            pytest.fail(f"no mid-bake moment to kill (rc {proc.poll()}, workers {workers})")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        left = wait_gone(workers, 5.0)
        assert not left, f"pool workers {left} outlived their SIGKILLed parent"
    finally:
        for p in workers:
            if alive(p):
                os.kill(p, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_watchdog_exits_a_worker_whose_parent_died(tmp_path: Path) -> None:
    """The portable fallback alone (prctl skipped): parent P starts worker W running ``_worker_init``;
    SIGKILL P; W exits within seconds. And a worker started after its parent died exits at once."""
    ready = tmp_path / "ready"
    worker = ("import os, sys, time; from prt_torch.bake import runner\n"
              "sys.platform = 'portable'  # skip prctl: only the watchdog thread remains\n"
              "runner._worker_init(os.getppid())\n"
              f"open({str(ready)!r}, 'w').close(); time.sleep(60)")
    parent = ("import subprocess, sys, time\n"
              f"w = subprocess.Popen([sys.executable, '-c', {worker!r}]); print(w.pid, flush=True); time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None
    w = int(p.stdout.readline())
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert ready.exists() and alive(w)
        p.kill()
        p.wait()
        assert not wait_gone([w], 5.0), "the watchdog did not end the orphaned worker"
    finally:
        if alive(w):
            os.kill(w, signal.SIGKILL)
        if p.poll() is None:
            p.kill()
            p.wait()
    out = subprocess.run([sys.executable, "-c", "from prt_torch.bake.runner import _worker_init; _worker_init(1); "
                          "print('alive')"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "alive" not in out.stdout
