"""Shared pytest fixtures.

* ``shared_data``: ``../shared/data`` (real glTF characters, HDR maps, BVH); tests that need it
  skip cleanly where ``../shared`` is absent.
* Session-wide fixtures that bake a small dataset or train a small run live in
  ``tests/fixtures_*.py`` and are registered below, so every test directory can use them.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PRT_SHARED", REPO.parent / "shared"))

pytest_plugins = [
    f"tests.{p.stem}" for p in sorted((REPO / "tests").glob("fixtures_*.py"))
]

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ``../shared/data``; skips the test where it is absent."""
    d = SHARED / "data"
    if not d.is_dir():
        pytest.skip("../shared/data is not present")
    return d
