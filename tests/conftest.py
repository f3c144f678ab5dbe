"""Shared pytest fixtures.

* ``shared_data``: ``../shared/data`` (real glTF characters, HDR maps, BVH); tests that need it
  skip cleanly where ``../shared`` is absent.
* Session-wide fixtures that bake a small dataset or train a small run live in
  ``tests/fixtures_*.py`` and are registered below, so every test directory can use them.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests.tolerance import checked_assert_array_equal

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PRT_SHARED", REPO.parent / "shared"))

pytest_plugins = [
    f"tests.{p.stem}" for p in sorted((REPO / "tests").glob("fixtures_*.py"))
]

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

# determinism policy (docs/DESIGN.md): exact comparisons of floating-point arrays say why equality holds
np.testing.assert_array_equal = checked_assert_array_equal


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ``../shared/data``; skips the test where it is absent."""
    d = SHARED / "data"
    if not d.is_dir():
        pytest.skip("../shared/data is not present")
    return d


@pytest.fixture(scope="session", autouse=True)
def _own_rpo_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Every test session builds its catalogue RPOs into its own cache (``PRT_CACHE``, inherited by the
    subprocesses tests run): what a session reads or writes never depends on an earlier run or on the user's
    ``~/.cache``, so the suite run twice in a row does the same work both times."""
    os.environ["PRT_CACHE"] = str(tmp_path_factory.mktemp("prt_cache"))
