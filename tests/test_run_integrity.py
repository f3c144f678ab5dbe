"""Run-directory integrity of ``prt train`` and ``prt export`` (issue 16).

Each stage's files are one committed unit: the metadata file (``model.json`` / ``export.json``), written
last with the sha256 of every file of the unit, is the commit record. The kill tests run the real command
in a subprocess whose :data:`prt_torch.io.before_replace` hook SIGKILLs it during its k-th atomic write
(temporary complete, not yet renamed), for every k of the stage; then every reader must see the old unit,
the new unit, or refuse with one line; and the next successful run leaves no temporary behind. Damaged
JSON (hypothesis) and a swapped ONNX graph must give one line too.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from prt_torch.errors import PrtError
from prt_torch.io import atomic_path, host_tag, parse_temporary
from prt_torch.rundir import RunDir
from tests.export.pipeline import TINY_CONFIG, build_tiny_run, copy_run

REPO = Path(__file__).resolve().parents[1]

#: the subprocess: kill itself during atomic write number argv[1] (0: never), log every write to argv[2]
DRIVER = r"""
import os, signal, sys
import prt_torch.io as io
k, log, n = int(sys.argv[1]), sys.argv[2], [0]
def hook(tmp, path):
    n[0] += 1
    with open(log, "a") as f:
        f.write(f"{n[0]} {path}\n")
    if n[0] == k:
        os.kill(os.getpid(), signal.SIGKILL)
io.before_replace = hook
from prt_torch.cli import main
sys.exit(main(sys.argv[3:]))
"""


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())


def _run_all(jobs: list[tuple[int, Path, list[str]]], parallel: int = 2) -> dict[int, tuple[int, str, list[str]]]:
    """Run the driver for each ``(k, log dir, prt args)``, ``parallel`` at a time ->
    ``{k: (returncode, stderr, logged writes)}``."""
    out, running, todo = {}, [], list(jobs)
    while todo or running:
        while todo and len(running) < parallel:
            k, d, args = todo.pop(0)
            log = d / f"writes.{k}.log"
            # each job its own empty RPO cache: whether a catalogue entry is written (one atomic write more)
            # must not depend on which job of the pool reached the shared cache first
            p = subprocess.Popen([sys.executable, "-c", DRIVER, str(k), str(log), *args], cwd=REPO,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                 env={**os.environ, "OMP_NUM_THREADS": "1", "PRT_CACHE": str(d / f"cache.{k}")})
            running.append((k, log, p))
        k, log, p = running.pop(0)
        _, err = p.communicate(timeout=300)
        out[k] = (p.returncode, err, log.read_text().splitlines() if log.is_file() else [])
    return out


def _temporaries(run: Path) -> list[Path]:
    return [p for d in RunDir(run).artifact_dirs if d.is_dir() for p in d.iterdir() if parse_temporary(p)]


def _one_line(exc: BaseException | str) -> str:
    msg = str(exc).strip()
    assert msg and "\n" not in msg, msg
    return msg


def _bundle_state(run: Path) -> dict | str:
    """The player's view: the export metadata it accepted, or its one-line refusal."""
    from prt_torch.player.bundle import RunBundle

    try:
        return RunBundle(run, graphs=("visibility",)).meta
    except PrtError as exc:
        msg = _one_line(exc)
        assert "prt export" in msg or "prt train" in msg, msg
        return msg


def _main_fails(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    from prt_torch.cli import main

    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    return _one_line(err)


# -- kill tests -------------------------------------------------------------------------------------------
def test_kill_train_at_every_write(tiny_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``prt train`` (another setting, so the new unit differs) killed at each of its atomic writes."""
    from prt_torch.config import load_config
    from prt_torch.fit.train import train_dataset
    from prt_torch.models.visibility import load_model

    old_meta = RunDir(tiny_run).model_meta()
    old_export = RunDir(tiny_run).export_meta()
    train_cfg = {**TINY_CONFIG["train"], "max_iter": 25}

    def job(k: int) -> tuple[int, Path, list[str]]:
        run = copy_run(tiny_run, tmp_path / f"run{k}")
        cfg = tmp_path / f"tiny{k}.yaml"
        cfg.write_text(yaml.safe_dump({**TINY_CONFIG, "train": train_cfg, "run_dir": str(run)}))
        return k, tmp_path, ["train", str(cfg)]

    # the lock holder's file, stages.json (key dropped), 2 models, model.pt, metrics.json, model.json, stages.json
    n = 8
    results = _run_all([job(k) for k in range(n + 1)])
    ref = results.pop(0)
    assert ref[0] == 0, ref[1][-2000:]
    writes = ref[2]
    assert len(writes) == n and "model.json" in writes[-2] and "stages.json" in writes[-1], writes
    n = len(writes)
    begin = 1 + next(i for i, w in enumerate(writes) if w.endswith("stages.json"))
    commit = len(writes) - 1  # model.json: the commit record
    full = RunDir(tmp_path / "run0")
    new_meta = full.model_meta()
    assert new_meta["files"] != old_meta["files"]
    assert "train" in full.stage_keys()
    stale = _bundle_state(full.path)  # a re-trained run with the old export: the player says to export
    assert isinstance(stale, str) and "stale" in stale and "prt export" in stale
    _main_fails(["play", str(full.path), "--clip", "wave", "--max-frames", "1", "--png", str(tmp_path / "png")],
                capsys)

    torn = 0
    for k, (rc, err, _) in sorted(results.items()):
        run = RunDir(tmp_path / f"run{k}")
        if k > n:
            assert rc == 0, (k, err[-2000:])  # fewer writes than the spare
            continue
        assert rc == -signal.SIGKILL, (k, err[-2000:])
        assert _temporaries(run.path), k  # the killed write's temporary
        assert k <= begin or "train" not in run.stage_keys(), k  # dropped first, set after the commit
        try:
            meta = run.model_meta()
        except PrtError as exc:
            torn += 1
            assert "prt train" in _one_line(exc) and str(run.model_json) in str(exc)
            for kind in (None, *old_meta["kinds"]):
                with pytest.raises(PrtError, match="prt train"):
                    load_model(run, kind)
            assert "prt train" in _main_fails(["eval", str(run.path), "--frames", "2"], capsys)
        else:  # the old unit intact (killed before the first model was renamed) or the new one committed
            assert meta == old_meta if k <= commit else meta["files"] != old_meta["files"], k
            for kind in (None, *meta["kinds"]):
                load_model(run, kind)
        state = _bundle_state(run.path)
        assert state == old_export or isinstance(state, str), k
        # the next successful run commits a new unit and leaves no temporary behind
        cfg = load_config(tmp_path / f"tiny{k}.yaml")
        train_dataset(run.dataset_path, run, cfg.train)
        assert not _temporaries(run.path), (k, _temporaries(run.path))
        assert run.model_meta()["files"] != old_meta["files"] and "train" in run.stage_keys()
    assert torn >= 2, (torn, n)  # at least the kills after the (different) mlp model, before model.json


def test_kill_export_at_every_write(tiny_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``prt export --force`` with other settings (1 RPO, k = 4) killed at each of its atomic writes."""
    from prt_torch.export.run import export_run

    old_export = RunDir(tiny_run).export_meta()
    args = ["--force", "--brdfs", "lambert", "--terms", "4"]

    def job(k: int) -> tuple[int, Path, list[str]]:
        run = copy_run(tiny_run, tmp_path / f"run{k}")
        return k, tmp_path, ["export", str(run), *args]

    # the lock holder's file, stages.json (key dropped), frames, the RPO cache entry (each job starts with an empty
    # cache), 1 RPO, 3 graphs, the compiled path's latent graph and decode arrays, blockers, shexp graph,
    # export.json, stages.json: the same sequence in every job
    n = 14
    results = _run_all([job(k) for k in range(n + 1)])
    ref = results.pop(0)
    assert ref[0] == 0, ref[1][-2000:]
    writes = ref[2]
    assert len(writes) == n and "export.json" in writes[-2] and "stages.json" in writes[-1], writes
    assert sum("rpo_cache" in w for w in writes) == 1, writes
    n = len(writes)
    begin = 1 + next(i for i, w in enumerate(writes) if w.endswith("stages.json"))
    commit = len(writes) - 1  # export.json: the commit record
    new = _bundle_state(tmp_path / "run0")
    assert isinstance(new, dict) and new["n_terms"] == 4 and new["brdfs"] == ["lambert"]

    torn = 0
    for k, (rc, err, _) in sorted(results.items()):
        run = RunDir(tmp_path / f"run{k}")
        if k > n:
            assert rc == 0, (k, err[-2000:])
            continue
        assert rc == -signal.SIGKILL, (k, err[-2000:])
        target = Path(writes[k - 1].split(" ", 1)[1].replace("run0", f"run{k}").replace("cache.0", f"cache.{k}"))
        assert any(parse_temporary(p) for p in target.parent.iterdir()), (k, target)  # killed mid-write there
        assert k <= begin or "export" not in run.stage_keys(), k
        state = _bundle_state(run.path)
        if isinstance(state, str):
            torn += 1
            assert "prt export" in state and str(run.export_json) in state
            with pytest.raises(PrtError, match="prt export"):
                run.export_meta()
            if torn == 1:  # `prt play` on a torn export: one line
                _main_fails(["play", str(run.path), "--clip", "wave", "--max-frames", "1", "--png",
                             str(tmp_path / "png")], capsys)
        else:  # old unit intact, or (killed at its stages.json key) the new one committed
            assert state == old_export if k <= commit else state["n_terms"] == 4, k
        export_run(run, brdfs=("lambert",), n_terms=4)
        assert not _temporaries(run.path), (k, _temporaries(run.path))
        assert _bundle_state(run.path)["n_terms"] == 4 and "export" in run.stage_keys()
    assert torn >= 2, (torn, n)  # at least the kills after the shading graph (k = 4 differs) before export.json


# -- swapped graph, temporaries ---------------------------------------------------------------------------
def test_swapped_graph_of_another_model_is_detected(tiny_run: Path, tmp_path: Path) -> None:
    from prt_torch.export.run import export_run

    run = copy_run(tiny_run, tmp_path / "run")
    other = copy_run(tiny_run, tmp_path / "other")
    export_run(other, kind="linear", brdfs=("lambert",), force=True)
    assert _bundle_state(run) == RunDir(tiny_run).export_meta()
    for graph in ("visibility", "fused"):
        shutil.copyfile(RunDir(other).graph_path(graph), RunDir(run).graph_path(graph))
        msg = _bundle_state(run)
        assert isinstance(msg, str) and f"{graph}.onnx" in msg and "prt export" in msg
        shutil.copyfile(RunDir(tiny_run).graph_path(graph), RunDir(run).graph_path(graph))
    shutil.copyfile(RunDir(other).model_path("linear"), RunDir(run).model_path("mlp"))  # model.json no longer agrees
    with pytest.raises(PrtError, match="models/mlp.pt is not the file it records"):
        RunDir(run).model_meta()


def test_stale_temporaries_removed_by_rule_and_never_read(tiny_run: Path, tmp_path: Path) -> None:
    """Temporaries of the stage's targets and of dead writers go at ``begin``; a live writer's stay; readers
    ignore all of them."""
    run = RunDir(copy_run(tiny_run, tmp_path / "run"))
    run.report_dir.mkdir(exist_ok=True)
    dead = 2**22 + 12345  # above the default pid_max: no such process
    host = host_tag()
    planted = {
        "target": run.path / f".visibility.onnx.{host}-1.abcdefgh.onnx",  # a live writer, but a target
        "dead": run.models_dir / f".mlp.pt.{host}-{dead}.abcd_efg.pt",
        "live": run.report_dir / f".results.json.{host}-1.abcdefgh.json",  # pid 1 is alive
        "legacy_old": run.rpo_dir / ".lambert.npz.k2j4h6g8.npz",
        "legacy_new": run.rpo_dir / ".phong.npz.k2j4h6g8.npz",
        "other_host": run.path / f".export.json.{'0' * 6 if host != '0' * 6 else '1' * 6}-7.abcdefgh.json",
    }
    for p in planted.values():
        p.write_bytes(b"garbage")
    past = time.time() - 7200
    os.utime(planted["legacy_old"], (past, past))
    assert all(parse_temporary(p) for p in planted.values())
    assert parse_temporary(run.path / "model.pt") is None and parse_temporary(run.path / ".prt.lock") is None
    assert isinstance(_bundle_state(run.path), dict)  # not picked up
    run.model_meta()
    with atomic_path(run.report_dir / "mine.json") as mine:  # this process's own temporary is never stale
        mine.write_text("{}")
        removed = run.begin("export", [run.graph_path("visibility")])
        assert mine.exists()
    assert sorted(removed) == sorted(planted[k] for k in ("target", "dead", "legacy_old"))
    assert all(planted[k].exists() for k in ("live", "legacy_new", "other_host"))


# -- damaged metadata (hypothesis) -----------------------------------------------------------------------
MODEL_KEYS = ("kinds", "default_kind", "files", "order", "n_coeffs", "n_vertices", "n_features")
EXPORT_KEYS = ("sh_order", "n_vertices", "n_features", "n_terms", "character_hash", "frames_file", "model_file",
               "model_sha256", "files", "rpo_files", "file_sha256")
BAD_VALUES = (None, "x", [], {}, True, 1.5, [1], {"a": 1})  # wrong types for every checked key


def _damage(text: str, keys: tuple[str, ...]) -> st.SearchStrategy[bytes]:
    obj = json.loads(text)
    hashes = "files" if "kinds" in obj else "file_sha256"

    def set_key(kv: tuple[str, object]) -> bytes:
        return json.dumps({**obj, kv[0]: kv[1]}).encode()

    def drop_key(k: str) -> bytes:
        return json.dumps({a: b for a, b in obj.items() if a != k}).encode()

    def flip_hash(i: int) -> bytes:
        files = dict(obj[hashes])
        name = sorted(files)[i % len(files)]
        files[name] = ("0" if files[name][0] != "0" else "1") + files[name][1:]
        return json.dumps({**obj, hashes: files}).encode()

    return st.one_of(
        st.sampled_from([b"", b"{}", b"[]", b"null", b"3", b'"text"', b"[{}]", b"\xff\xfe{", b"{\"kinds\": "]),
        st.binary(max_size=48),
        st.integers(0, len(text) - 1).map(lambda n: text.encode()[:n]),  # truncated
        st.tuples(st.sampled_from(keys), st.sampled_from(BAD_VALUES)).map(set_key),
        st.sampled_from(keys).map(drop_key),
        st.integers(0, 50).map(flip_hash),
    )


@pytest.fixture(scope="module")
def damage_run(tiny_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return copy_run(tiny_run, tmp_path_factory.mktemp("damage") / "run")


def _check_damage(run: RunDir, path: Path, original: bytes, bad: bytes, readers: list) -> None:
    path.write_bytes(bad)
    try:
        try:
            same = json.loads(bad) == json.loads(original)
        except (ValueError, UnicodeDecodeError):
            same = False
        for read in readers:
            if same:
                read()
                continue
            with pytest.raises(PrtError) as exc:
                read()
            msg = _one_line(exc.value)
            assert path.name in msg or "is not the character this run was made for" in msg, msg
    finally:
        path.write_bytes(original)


def test_damaged_model_json(damage_run: Path) -> None:
    from prt_torch.models.visibility import load_model

    run = RunDir(damage_run)
    original = run.model_json.read_bytes()

    @settings(derandomize=True, deadline=None, max_examples=60)
    @given(_damage(original.decode(), MODEL_KEYS))
    def check(bad: bytes) -> None:
        _check_damage(run, run.model_json, original, bad, [run.model_meta, lambda: load_model(run, "linear")])

    check()


def test_damaged_export_json(damage_run: Path) -> None:
    from prt_torch.player.bundle import RunBundle

    run = RunDir(damage_run)
    original = run.export_json.read_bytes()

    @settings(derandomize=True, deadline=None, max_examples=60)
    @given(_damage(original.decode(), EXPORT_KEYS))
    def check(bad: bytes) -> None:
        _check_damage(run, run.export_json, original, bad, [run.export_meta, lambda: RunBundle(run, graphs=())])

    check()


@pytest.mark.parametrize("bad", [b"{}", b"garbage", b"[1, 2]"])
def test_damaged_metadata_through_the_cli(damage_run: Path, tmp_path: Path, bad: bytes,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    run = RunDir(damage_run)
    for path, argv in ((run.model_json, ["eval", str(run.path), "--frames", "2"]),
                       (run.export_json, ["play", str(run.path), "--clip", "wave", "--max-frames", "1", "--png",
                                          str(tmp_path / "png")])):
        original = path.read_bytes()
        path.write_bytes(bad)
        try:
            msg = _main_fails(argv, capsys)
            assert path.name in msg and ("prt train" in msg or "prt export" in msg), msg
        finally:
            path.write_bytes(original)
