"""A copy of the session's tiny exported run (tests/export/pipeline.py) with its sphere blockers and SHEXP graph
(shipped here when the export did not write them), for the scene, player and compare tests."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.export.pipeline import build_tiny_run


def scene_run_copy(base: Path, name: str) -> Path:
    from prt_torch.rundir import RunDir

    src = build_tiny_run(base)
    dst = base / name
    if not dst.is_dir():
        shutil.copytree(src, dst)
        run = RunDir(dst)
        if not (run.shexp_path.is_file() and run.blockers_path.is_file()):
            from prt_torch.shexp.graph import ship_shexp

            ship_shexp(run, run.character(), int(run.export_meta()["sh_order"]), 32)
    return dst


@pytest.fixture(scope="session")
def scene_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An exported tiny run (built-in character, density 0.1, order 4) with blockers and ``shexp.onnx``."""
    return scene_run_copy(tmp_path_factory.getbasetemp(), "scene_run")
