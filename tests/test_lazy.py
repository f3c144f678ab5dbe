"""prt_torch.lazy: a package's exports import their submodule on first access, and an export named like its own
submodule stays the export once the submodule is imported (as an eager ``from .sub import sub`` kept it)."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest


@pytest.fixture
def planted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    pkg = tmp_path / "planted_lazy"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "from prt_torch.lazy import lazy_exports\n"
        "lazy_exports(__name__, {'planted_lazy.heavy': ('Heavy',), 'planted_lazy.same': ('same',)})\n")
    (pkg / "heavy.py").write_text("class Heavy:\n    pass\n")
    (pkg / "same.py").write_text("def same():\n    return 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield "planted_lazy"
    for name in [m for m in sys.modules if m.split(".")[0] == "planted_lazy"]:
        del sys.modules[name]


def test_exports_import_on_first_access(planted: str) -> None:
    pkg = importlib.import_module(planted)
    assert f"{planted}.heavy" not in sys.modules
    assert "Heavy" in dir(pkg)
    heavy = pkg.Heavy
    assert f"{planted}.heavy" in sys.modules and heavy is sys.modules[f"{planted}.heavy"].Heavy
    with pytest.raises(AttributeError, match="has no attribute 'missing'"):
        _ = pkg.missing


def test_export_named_like_its_submodule_stays_the_export(planted: str) -> None:
    pkg = importlib.import_module(planted)
    importlib.import_module(f"{planted}.same")  # the import system binds the submodule on the package
    assert callable(pkg.same) and pkg.same() == 42
    names: dict[str, object] = {}
    exec(f"from {planted} import same", names)  # the from-import path (a planted package, not a dependency)
    assert names["same"] is pkg.same
