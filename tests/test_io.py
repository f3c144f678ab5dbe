"""Atomic writes: the target is either the old or the new content, never torn; failures leave no litter."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from prt_torch.io import atomic_path, atomic_write_json, atomic_write_text


def test_replace_and_permissions(tmp_path: Path) -> None:
    p = tmp_path / "a" / "b.json"
    atomic_write_json(p, {"x": 1})
    atomic_write_json(p, {"x": 2})
    assert p.read_text().strip().endswith("}") and '"x": 2' in p.read_text()
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask
    assert [q.name for q in p.parent.iterdir()] == ["b.json"]


def test_failure_keeps_old_file_and_cleans_up(tmp_path: Path) -> None:
    p = tmp_path / "x.txt"
    atomic_write_text(p, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(p) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash mid-write")
    assert p.read_text() == "old"
    assert [q.name for q in tmp_path.iterdir()] == ["x.txt"]


def test_suffix_is_kept_for_format_sniffing(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "m.onnx") as tmp:
        assert tmp.suffix == ".onnx" and tmp.parent == tmp_path
        tmp.write_bytes(b"1")
