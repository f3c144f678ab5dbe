"""Scene config: the schema, one-line errors, the run config's ``scene:`` section and configs/scene2.yaml."""

from __future__ import annotations

from pathlib import Path

import pytest

from prt_torch.config import config_from_dict, load_config
from prt_torch.errors import PrtError
from prt_torch.scene.config import SceneConfig, scene_from_dict
from prt_torch.scene.load import load_scene

REPO = Path(__file__).resolve().parents[2]


def test_defaults_and_entries() -> None:
    s = scene_from_dict({"ground": {}})
    assert s.ground is not None and s.ground.resolution == 64 and s.ground.z == "auto" and s.ground.size == "auto"
    assert len(s.entries()) == 1 and s.entries()[0].run is None
    assert scene_from_dict({"ground": {"albedo": [0.1, 0.2, 0.3]}}).ground.albedo_rgb() == (0.1, 0.2, 0.3)
    assert SceneConfig().ground is None


@pytest.mark.parametrize("bad, key", [
    ({"ground": {"resolution": 0}}, "scene.ground.resolution"),
    ({"ground": {"size": -1.0}}, "scene.ground.size"),
    ({"ground": {"albedo": [0.5, 2.0, 0.1]}}, "scene.ground.albedo"),
    ({"ground": {"z": "lowest"}}, "scene.ground.z"),
    ({"characters": [{"offset": [0, 1]}]}, "scene.characters.0.offset"),
    ({"characters": [{"clip": "walk", "colour": 1}]}, "scene.characters.0.colour"),
    ({"floor": {}}, "scene.floor"),
    ({"characters": [{"yaw_deg": float("nan")}]}, "scene.characters.0.yaw_deg"),
])
def test_bad_scene_is_one_line_error(bad: dict, key: str) -> None:
    with pytest.raises(PrtError) as e:
        scene_from_dict(bad)
    msg = str(e.value)
    assert "\n" not in msg and key in msg


def test_run_config_scene_section(tmp_path: Path) -> None:
    base = {"name": "x", "character": {"source": "builtin", "train_clips": ["walk"]}}
    assert config_from_dict(base).scene is None
    cfg = config_from_dict({**base, "scene": {"ground": {"resolution": 8}}})
    assert cfg.scene.ground.resolution == 8
    with pytest.raises(PrtError, match="scene"):
        config_from_dict({**base, "scene": {"ground": {"resolution": "many"}}})


def test_shipped_scene_configs() -> None:
    demo = load_config(REPO / "configs" / "demo.yaml")
    assert demo.scene is not None and demo.scene.ground is not None
    two = load_scene(str(REPO / "configs" / "scene2.yaml"))
    assert two.ground is not None and len(two.characters) == 2
    assert two.characters[0].offset != two.characters[1].offset
