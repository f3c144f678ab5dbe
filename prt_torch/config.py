"""Run configuration: one YAML file per character/run, validated with pydantic.

A config has sections owned by the stage that reads them::

    name: builtin                 # run name; artifacts go to runs/<name>/ unless run_dir is set
    character: {...}              # prt_torch.rig.config.CharacterConfig
    bake: {...}                   # prt_torch.bake.config.BakeConfig
    train: {...}                  # prt_torch.fit.config.TrainConfig

Unknown keys anywhere are errors (``extra="forbid"``); :func:`load_config` turns any validation
problem into a one-line :class:`prt_torch.PrtError` naming the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from prt_torch.bake.config import BakeConfig
from prt_torch.errors import PrtError
from prt_torch.fit.config import TrainConfig
from prt_torch.rig.config import CharacterConfig


class RunConfig(BaseModel):
    """The whole job: which character, how to bake it, how to fit it, where to write."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    run_dir: Path | None = None
    character: CharacterConfig
    bake: BakeConfig = Field(default_factory=BakeConfig)
    train: TrainConfig = Field(default_factory=TrainConfig)

    #: directory of the config file, used to resolve relative paths inside it
    base_dir: Path | None = Field(default=None, exclude=True)

    def resolve(self, p: str | Path) -> Path:
        """Resolve a path from the config relative to the config file's directory."""
        p = Path(p).expanduser()
        if p.is_absolute() or self.base_dir is None:
            return p
        return (self.base_dir / p).resolve()

    @property
    def out_dir(self) -> Path:
        """``runs/<name>`` (relative to the working directory) unless ``run_dir`` is set."""
        return self.run_dir if self.run_dir is not None else Path("runs") / self.name


def _format_validation_error(exc: ValidationError, source: str) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"]) or "<root>"
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown config key '{loc}'"
    if err["type"] == "missing":
        return f"{source}: missing config key '{loc}'"
    return f"{source}: bad value for '{loc}': {err['msg']}"


def config_from_dict(data: dict[str, Any], source: str = "config", base_dir: Path | None = None) -> RunConfig:
    """Validate a plain dict as a :class:`RunConfig` (one-line :class:`PrtError` on failure)."""
    if not isinstance(data, dict):
        raise PrtError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        cfg = RunConfig.model_validate(data)
    except ValidationError as exc:
        raise PrtError(_format_validation_error(exc, source)) from None
    cfg.base_dir = base_dir
    return cfg


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a YAML run config."""
    path = Path(path)
    if not path.is_file():
        raise PrtError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise PrtError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return config_from_dict(data, source=str(path), base_dir=path.parent.resolve())
