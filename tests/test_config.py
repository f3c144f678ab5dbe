"""Run configs: the shipped ones validate; every bad config is one line naming the key."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from prt_torch.config import load_config
from prt_torch.errors import PrtError

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "configs").glob("*.yaml")))
def test_shipped_configs_validate(name: str) -> None:
    path = REPO / "configs" / name
    if set(yaml.safe_load(path.read_text())) == {"scene"}:  # a scene file (`prt play RUN --scene FILE`)
        from prt_torch.scene.load import load_scene

        assert load_scene(str(path)).characters
        return
    cfg = load_config(path)
    assert cfg.name and cfg.bake.order >= 1
    assert cfg.out_dir == REPO / "runs" / cfg.name or cfg.run_dir is not None  # the checkout's, from any cwd


@pytest.mark.parametrize(
    "text, match",
    [
        ("name: x\ncharacter: {}\nbake: {raays: 3}\n", "unknown config key 'bake.raays'"),
        ("character: {}\n", "missing config key 'name'"),
        ("name: x\ncharacter: {}\nbake: {order: 99}\n", "bad value for 'bake.order'"),
        ("name: x\ncharacter: [\n", "not valid YAML"),
        ("- 1\n- 2\n", "mapping at the top level"),
    ],
)
def test_bad_configs(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(PrtError, match=match) as info:
        load_config(p)
    assert "\n" not in str(info.value)


def test_missing_config_file() -> None:
    with pytest.raises(PrtError, match="config file not found"):
        load_config("does/not/exist.yaml")


def test_cli_prints_one_line_without_traceback(tmp_path: Path) -> None:
    p = tmp_path / "c.yaml"
    p.write_text("name: x\ncharacter: {sorce: builtin}\n")
    r = subprocess.run([sys.executable, "-m", "prt_torch", "bake", str(p)], capture_output=True, text=True,
                       cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["error: " + f"{p}: unknown config key 'character.sorce'"]
    assert not (tmp_path / "runs").exists()
