"""Reading a scene YAML file: the scene section (:mod:`prt_torch.scene.config`, a schema every stage reads) parsed
by the run config's bounded YAML reader (:func:`prt_torch.config.parse_yaml`), which imports every schema.
"""

from __future__ import annotations

from pathlib import Path

from prt_torch import limits as L
from prt_torch.config import parse_yaml
from prt_torch.errors import PrtError
from prt_torch.scene.config import SceneConfig, scene_from_dict


def load_scene(path: str) -> SceneConfig:
    """A scene YAML file (a whole run config with a ``scene:`` section, or just the section)."""
    p = Path(path)
    if not p.is_file():
        raise PrtError(f"scene file not found: {p}")
    if p.stat().st_size > L.MAX_CONFIG_BYTES:
        raise PrtError(f"{p}: scene file over the {L.MAX_CONFIG_BYTES} byte bound")
    return scene_from_dict(parse_yaml(p.read_text(encoding="utf-8"), str(p)), str(p))
