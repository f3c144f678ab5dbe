"""Session fixture: the tiny end-to-end run (built once, see tests/export/pipeline.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.export.pipeline import build_tiny_run


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tiny_run(tmp_path_factory.getbasetemp())
