"""Store integrity: crc32c chunks, missing chunks of done frames, readers' one-line errors, repair by ``prt bake``.

Damage is made by hand on copies of one uninterrupted bake of the tiny config of ``test_runner``: a
deleted chunk file (it would read back as zeros) and garbled chunk bytes (zstd errors, or silently wrong
numbers without a checksum). Every case must be caught by the readers (one-line :class:`PrtError`
naming the array and frames) and by :meth:`BakedDataset.verify`, and a resumed bake must restore the
bitwise-identical arrays.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.codecs import Crc32cCodec

from prt_torch.bake.runner import bake, run_bake
from prt_torch.bake.store import FORMAT_VERSION, BakedDataset
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from tests.bake.test_runner import assert_same, read_all, tiny_config

#: generated damage cases (seeded): each a random chunk file of the store and a random byte offset
N_CASES = 16


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    """An undamaged in-process bake of the tiny config (run directory, its arrays)."""
    run_dir = tmp_path_factory.mktemp("integrity_ref")
    path = bake(config_from_dict(tiny_config(run_dir)), workers=1, progress=False)
    return run_dir, read_all(path)


def copy_run(reference: tuple[Path, dict], dst: Path) -> Path:
    """A copy of the reference run directory; returns its dataset path."""
    shutil.copytree(reference[0], dst)
    return dst / "dataset.zarr"


def chunk_files(path: Path) -> list[Path]:
    """Every chunk file of a store, sorted (``<array>/c/...``)."""
    return sorted(p for p in path.rglob("*") if p.is_file() and "c" in p.relative_to(path).parts[1:2])


def read_everything(path: Path) -> None:
    """Read what training and evaluation read: both splits with every per-frame array, the static arrays."""
    ds = BakedDataset(path)
    for split in ds.splits:
        ds.split(split, extra=("positions", "normals", "frames"))
    for name in ("faces", "cluster", "cluster_axis", "cluster_bone"):
        getattr(ds, name)


def reader_error(path: Path) -> str:
    """The reader's error message on a damaged store (fails the test when reading succeeds)."""
    with pytest.raises(PrtError) as exc:
        read_everything(path)
    msg = str(exc.value)
    assert "\n" not in msg and "prt bake" in msg and "array '" in msg, msg
    return msg


def garble(p: Path, offset: int) -> None:
    """Flip the bits of one byte of file ``p``."""
    b = bytearray(p.read_bytes())
    b[offset % len(b)] ^= 0xFF
    p.write_bytes(bytes(b))


def test_new_store_has_checksums_and_every_chunk(reference: tuple[Path, dict]) -> None:
    path = reference[0] / "dataset.zarr"
    ds = BakedDataset(path)
    assert ds.format_version == FORMAT_VERSION == 2
    g = zarr.open_group(str(path), mode="r")
    for name in g.array_keys():
        assert isinstance(g[name].metadata.codecs[-1], Crc32cCodec), name
    report = ds.verify(checksums=True)
    assert report.ok and report.chunks == len(chunk_files(path))  # every chunk written, even all-zero ones
    assert (path / "clip_id" / "c" / "0").is_file()  # clip 0's ids are all zero (= the fill value)


def test_deleted_chunk_is_detected_and_rebaked(tmp_path: Path, reference: tuple[Path, dict]) -> None:
    path = copy_run(reference, tmp_path / "run")
    (path / "visibility" / "c" / "2" / "0" / "0").unlink()  # frames 8-11, done: would read as zeros
    msg = reader_error(path)
    assert "array 'visibility' frames 8-11" in msg and "missing chunk" in msg
    report = BakedDataset(path).verify()
    assert report.blocks == [(8, 12)] and report.static == []
    res = run_bake(config_from_dict(tiny_config(tmp_path / "run")), workers=1, progress=False)
    assert res.repaired == 4 and res.frames == 4 and res.skipped == len(reference[1]["done"]) - 4
    assert_same(read_all(path), reference[1])
    assert BakedDataset(path).verify(checksums=True).ok


def test_garbled_chunk_is_detected_and_rebaked_by_the_cli(tmp_path: Path, reference: tuple[Path, dict]) -> None:
    import json
    import subprocess
    import sys

    path = copy_run(reference, tmp_path / "run")
    garble(path / "positions" / "c" / "5" / "0" / "0", 40)  # frames 20-23
    msg = reader_error(path)
    assert "array 'positions' frames 20-23" in msg and "checksum" in msg
    assert BakedDataset(path).verify().ok  # listing the chunks alone cannot see garbled bytes ...
    assert BakedDataset(path).verify(checksums=True).blocks == [(20, 24)]  # ... decoding does
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps(tiny_config(tmp_path / "unused")))
    out = subprocess.run([sys.executable, "-m", "prt_torch.cli", "bake", str(cfg), "--run-dir", str(tmp_path / "run"),
                          "--workers", "1", "--no-progress", "--json"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "repairing" in out.stderr and "re-baking 4 frame(s) in 1 block(s)" in out.stderr
    assert json.loads(out.stdout)["frames"] == 4
    assert_same(read_all(path), reference[1])


def test_generated_damage_is_detected_and_repaired(tmp_path: Path, reference: tuple[Path, dict]) -> None:
    """N_CASES seeded cases: a random chunk file of any array (data, done, creation-time arrays), deleted or
    with one byte flipped at a random offset; each is caught by the reader and by verify(checksums=True).
    Then all cases at once on one copy: one resumed bake restores the reference bitwise."""
    rng = np.random.default_rng(16)
    files = chunk_files(reference[0] / "dataset.zarr")
    picks = rng.choice(len(files), N_CASES, replace=False)
    cases = []
    for k, i in enumerate(picks):
        rel = files[i].relative_to(reference[0])
        array = rel.parts[1]
        delete = bool(rng.integers(2)) and array != "done"  # a deleted done chunk just means "not baked yet"
        cases.append((rel, array, delete, int(rng.integers(1 << 30))))
        path = copy_run(reference, tmp_path / f"case{k}")
        target = tmp_path / f"case{k}" / rel
        target.unlink() if delete else garble(target, cases[-1][3])
        msg = reader_error(path)
        assert f"array '{array}'" in msg, (rel, delete, msg)
        report = BakedDataset(path).verify(checksums=True)
        assert [d.array for d in report.damage] == [array], (rel, delete, report)
    assert len({c[1] for c in cases}) >= 5  # the draw covers many arrays
    # every case at once (distinct files), one resume
    path = copy_run(reference, tmp_path / "all")
    for rel, _, delete, offset in cases:
        target = tmp_path / "all" / rel
        target.unlink() if delete else garble(target, offset)
    res = run_bake(config_from_dict(tiny_config(tmp_path / "all")), workers=1, progress=False)
    assert res.repaired > 0
    assert_same(read_all(path), reference[1])
    assert BakedDataset(path).verify(checksums=True).ok
    read_everything(path)


def test_format_1_store_is_read_resumed_and_repaired(tmp_path: Path, reference: tuple[Path, dict],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A store of the previous layout (no checksums, all-fill chunks not written) still reads, resumes and
    has its missing done chunks detected and re-baked."""
    cfg = config_from_dict(tiny_config(tmp_path / "old"))
    with monkeypatch.context() as m:
        m.setattr("prt_torch.bake.runner.FORMAT_VERSION", 1)
        path = bake(cfg, workers=1, progress=False)
    ds = BakedDataset(path)
    assert ds.format_version == 1 and not (path / "clip_id" / "c" / "0").exists()  # all zero: not written
    assert ds.verify(checksums=True).ok
    read_everything(path)
    (path / "frames" / "c" / "1" / "0" / "0" / "0").unlink()
    assert "array 'frames' frames 4-7" in reader_error(path)
    res = run_bake(cfg, workers=1, progress=False)
    assert res.repaired == 4 and res.frames == 4
    assert BakedDataset(path).format_version == 1
    assert_same(read_all(path), reference[1])
