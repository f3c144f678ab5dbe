"""Scene section of a run config (owned by :mod:`prt_torch.scene`): a ground plane and several characters.

::

    scene:
      ground:                      # omit (or null) for no floor
        size: auto                 # side length (world units) of the square ground; auto: see GroundConfig
        resolution: 64             # cells per side (64 -> 65 x 65 vertices, 8192 triangles)
        z: auto                    # height of the plane: auto = lowest rest-mesh point, clip = lowest posed
                                   # vertex over the scene's clips (the feet), or a number
        albedo: 0.6                # diffuse albedo (a number or [r, g, b])
      camera: {azimuth_deg: -35, elevation_deg: 26}   # optional; default: the player's camera
      characters:                  # empty: the run's own character at the origin, its held-out clip
        - {run: null, clip: wave, offset: [0, 0, 0], yaw_deg: 0, time_offset: 0}
        - {run: runs/other, clip: walk, offset: [1.5, 0, 0], yaw_deg: 90, time_offset: 0.5}

``run: null`` (the default) is the run being played / compared; ``clip: null`` is that run's held-out clip
(the player: the clip asked for on the command line). ``time_offset`` (seconds) shifts a character's clip
(it loops). Every value is finite and bounded; a bad value is a one-line :class:`~prt_torch.errors.PrtError`
naming the key (:func:`scene_from_dict`, or the run config's validation).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from prt_torch import limits as L
from prt_torch.errors import PrtError

#: at most this many characters in one scene
MAX_CHARACTERS = 16
#: ground cells per side
MAX_GROUND_RESOLUTION = 1024


class GroundConfig(BaseModel):
    """The ground receiver: a square tessellated plane, normal ``+z``.

    ``size: auto`` = the characters' xy extent (rest meshes, placed) plus 1.5 rest heights on every side
    (the tallest character's), so soft shadows of a low sun stay on the floor. ``z: auto`` = the lowest
    rest-mesh point of the placed characters; ``z: clip`` = the lowest posed vertex over the clips played
    (the feet, for a clip whose root moves up or down).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    size: float | Literal["auto"] = "auto"
    resolution: int = Field(default=64, ge=1, le=MAX_GROUND_RESOLUTION)
    z: float | Literal["auto", "clip"] = "auto"
    albedo: float | list[float] = 0.6

    @field_validator("size")
    @classmethod
    def _size(cls, v: Any) -> Any:
        if not isinstance(v, str) and not (0.0 < v <= L.MAX_HEIGHT):
            raise ValueError(f"must be in (0, {L.MAX_HEIGHT}] or 'auto', got {v}")
        return v

    @field_validator("z")
    @classmethod
    def _z(cls, v: Any) -> Any:
        if not isinstance(v, str) and abs(v) > L.MAX_HEIGHT:
            raise ValueError(f"must be within +-{L.MAX_HEIGHT}, 'auto' or 'clip', got {v}")
        return v

    @field_validator("albedo")
    @classmethod
    def _albedo(cls, v: Any) -> Any:
        vals = [v] if not isinstance(v, list) else v
        if len(vals) not in (1, 3):
            raise ValueError(f"must be a number or [r, g, b], got {len(vals)} values")
        if not all(0.0 <= x <= 1.0 for x in vals):
            raise ValueError(f"every albedo must be in [0, 1], got {v}")
        return v

    def albedo_rgb(self) -> tuple[float, float, float]:
        a = self.albedo if isinstance(self.albedo, list) else [self.albedo]
        a = a * 3 if len(a) == 1 else a
        return (float(a[0]), float(a[1]), float(a[2]))


class SceneCharacter(BaseModel):
    """One character of the scene: the exported run that animates it, its clip and placement."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    run: str | None = Field(default=None, max_length=L.MAX_STRING_LENGTH)
    clip: str | None = Field(default=None, min_length=1, max_length=L.MAX_NAME_LENGTH)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_deg: float = Field(default=0.0, ge=-3600.0, le=3600.0)
    time_offset: float = Field(default=0.0, ge=-L.MAX_CLIP_SECONDS, le=L.MAX_CLIP_SECONDS)

    @field_validator("offset")
    @classmethod
    def _offset(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if max(abs(x) for x in v) > L.MAX_HEIGHT:
            raise ValueError(f"every offset component must be within +-{L.MAX_HEIGHT}, got {list(v)}")
        return v


class SceneCamera(BaseModel):
    """Where the scene's camera looks from: the player's orbit camera (:func:`prt_torch.player.player.camera_eye`)
    at ``azimuth_deg`` (0 = in front of the character, on -y; negative swings the camera toward -x) and
    ``elevation_deg`` above the horizon. A raised camera shows the floor and the shadow on it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    azimuth_deg: float = Field(default=0.0, ge=-360.0, le=360.0)
    elevation_deg: float = Field(default=11.5, ge=-89.0, le=89.0)


class SceneConfig(BaseModel):
    """A scene: optional ground, characters (empty: the run's own character at the origin), optional camera
    (default: the player's camera)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    ground: GroundConfig | None = None
    characters: list[SceneCharacter] = Field(default_factory=list, max_length=MAX_CHARACTERS)
    camera: SceneCamera | None = None

    def entries(self) -> list[SceneCharacter]:
        """The characters, or the one default entry (the run's own character) when none are listed."""
        return list(self.characters) if self.characters else [SceneCharacter()]


def scene_from_dict(data: Any, source: str = "scene") -> SceneConfig:
    """Validate ``data`` (the ``scene:`` mapping, or a whole config holding one) -> :class:`SceneConfig`;
    any problem is a one-line :class:`PrtError` naming the key."""
    if isinstance(data, dict) and "scene" in data:
        data = data["scene"]
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise PrtError(f"{source}: the scene must be a mapping, got {type(data).__name__}")
    try:
        return SceneConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(x) for x in err.get("loc", ())) or "scene"
        msg = " ".join(str(err.get("msg", "invalid value")).split())
        if err.get("type") == "extra_forbidden":
            msg = "unknown key"
        raise PrtError(f"{source}: scene.{loc}: {msg}") from None


def run_scene(run: Any) -> SceneConfig | None:
    """The scene a run directory records (``RunDir.scene_json``, written by ``prt demo``), or ``None``."""
    path = run.scene_json
    if not path.is_file():
        return None
    return scene_from_dict(run.read_json(path), str(path))


def write_run_scene(run: Any, scene: SceneConfig) -> None:
    """Record ``scene`` in the run directory (atomically)."""
    from prt_torch.io import atomic_write_json

    atomic_write_json(run.scene_json, scene.model_dump(mode="json"))
