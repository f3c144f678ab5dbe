"""The ``cloth:`` section of a run config (owned by :mod:`prt_torch.cloth`): scene, cloth sheet, material,
time stepping, wind patterns (flag) and limits of the blow-up detector.

Units: metres, kilograms, seconds; angles in degrees. The cloth is a ``rows x cols`` grid of vertices
(``rows`` along the hanging direction: down the cape / down the flag's pole, ``cols`` across: along the
cape's shoulders / away from the pole), ``width x height`` metres, ``areal_density`` kg/m^2.

Simulation (:mod:`prt_torch.cloth.simulate`, MuJoCo flex): each output frame (``fps``; ``None`` =
``character.fps``, the cape's clips are sampled at it) is ``substeps`` MuJoCo steps, so the timestep is
``1 / (fps * substeps)``. Edges are inextensible up to the soft equality constraint (time constant
``edge_timeconst`` timesteps, MuJoCo's ``solref``); bending is MuJoCo's 2D shell (``young``, ``poisson``,
``thickness``, ``damping``); air drag on the triangles (``air_density``, ``drag``) carries the wind.

Sequences: the flag simulates one sequence per wind pattern (``train_winds`` / ``heldout_winds``, named by
their ``name``); the cape one per ``character.train_clips`` / ``heldout_clips`` entry (the body's clips drive
it). Each sequence starts with ``settle_frames`` unrecorded frames (the body blends from the bind pose to the
sequence's first frame in the first half and holds it; the wind rises from 0 in the first half).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from prt_torch import limits as L

#: bound on the grid size along one side (``rows``, ``cols``)
MAX_GRID_SIDE = 1024


class WindPattern(BaseModel):
    """One flag sequence's wind: mean ``speed`` (m/s) blowing toward azimuth ``direction_deg`` (degrees in the
    horizontal plane, 0 = +x: along the flag, away from the pole; 90 = +y) tilted up by ``elevation_deg``, with
    gusts of ``gust_amplitude`` m/s (a seeded sum of sines around ``gust_frequency`` Hz, travelling downwind at
    the mean speed) and a direction wobble of ``gust_direction_deg``; ``frames`` recorded frames."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$", max_length=L.MAX_NAME_LENGTH)
    speed: float = Field(default=6.0, ge=0.0, le=60.0)
    direction_deg: float = Field(default=0.0, ge=-360.0, le=360.0)
    elevation_deg: float = Field(default=0.0, ge=-60.0, le=60.0)
    gust_amplitude: float = Field(default=2.0, ge=0.0, le=60.0)
    gust_frequency: float = Field(default=0.5, gt=0.0, le=20.0)
    gust_direction_deg: float = Field(default=10.0, ge=0.0, le=90.0)
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)
    frames: int = Field(default=60, ge=1, le=L.MAX_FRAMES)


class ClothConfig(BaseModel):
    """The simulated cloth of a deformable run (``cloth:`` of :class:`prt_torch.config.RunConfig`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    scene: Literal["cape", "flag"]
    rows: int = Field(default=64, ge=3, le=MAX_GRID_SIDE)
    cols: int = Field(default=32, ge=3, le=MAX_GRID_SIDE)
    width: float | None = Field(default=None, gt=0.0, le=20.0)  # None: cape 0.46 m, flag 1.2 m
    height: float | None = Field(default=None, gt=0.0, le=20.0)  # None: cape 0.8 m, flag 0.8 m
    areal_density: float = Field(default=0.2, gt=0.0, le=50.0)  # kg/m^2 (cotton ~0.15-0.3)
    young: float = Field(default=5.0e3, gt=0.0, le=1.0e12)  # Pa, bending shell (B = E t^3 / 12 ~ 3e-6 N m)
    poisson: float = Field(default=0.3, ge=0.0, lt=0.5)
    thickness: float = Field(default=2.0e-3, gt=0.0, le=0.1)  # m
    damping: float = Field(default=1.0e-3, ge=0.0, le=10.0)  # shell (bending) damping, s
    edge_timeconst: float = Field(default=2.0, ge=1.0, le=100.0)  # edge constraint time constant, in timesteps
    contact_timeconst: float = Field(default=0.002, gt=0.0, le=1.0)  # cape: contact time constant, s (>= 2 dt)
    radius: float = Field(default=0.006, gt=0.0, le=0.5)  # collision radius of the cloth, m
    collider_gap: float = Field(default=0.01, ge=0.0, le=0.5)  # cape: rest cloth clearance from the body, m
    friction: float = Field(default=0.6, ge=0.0, le=10.0)
    condim: Literal[1, 3] = 3  # cape: body contacts frictionless (1) or with friction (3)
    fps: float | None = Field(default=None, gt=0.0, le=L.MAX_FPS)  # None: character.fps
    substeps: int = Field(default=16, ge=1, le=10_000)  # MuJoCo steps per output frame
    solver: Literal["CG", "Newton", "PGS"] = "PGS"  # MuJoCo constraint solver (PGS: stable with contacts)
    iterations: int = Field(default=20, ge=1, le=1000)  # constraint solver iterations per step
    gravity: float = Field(default=9.81, ge=0.0, le=100.0)
    air_density: float = Field(default=1.2, ge=0.0, le=100.0)  # kg/m^3
    drag: float = Field(default=1.0, ge=0.0, le=10.0)  # normal pressure drag coefficient of a triangle
    skin_friction: float = Field(default=0.02, ge=0.0, le=10.0)  # tangential drag coefficient
    pin_edge: bool = True  # flag: pin the pole edge (False: a free sheet, e.g. to drop it)
    flag_top: float = Field(default=2.0, ge=-100.0, le=100.0)  # flag: z of the pole's top, m
    train_winds: list[WindPattern] = Field(default_factory=list, max_length=L.MAX_LIST_LENGTH)
    heldout_winds: list[WindPattern] = Field(default_factory=list, max_length=L.MAX_LIST_LENGTH)
    append_pose: bool = False  # cape: append the body's pose features to the cloth features
    seed: int = Field(default=0, ge=0, le=L.MAX_SEED)
    settle_frames: int = Field(default=30, ge=0, le=L.MAX_FRAMES)
    workers: int = Field(default=1, ge=0, le=L.MAX_WORKERS)  # parallel sequences (0: one per core)
    max_strain: float = Field(default=1.0, gt=0.0, le=100.0)  # blow-up: an edge longer than (1 + this) x rest
    max_speed: float = Field(default=60.0, gt=0.0, le=1.0e6)  # blow-up: a vertex faster than this, m/s

    @model_validator(mode="after")
    def _scene(self) -> ClothConfig:
        if self.scene == "flag":
            names = [w.name for w in self.train_winds + self.heldout_winds]
            if not self.train_winds:
                raise ValueError("train_winds: the flag needs at least one training wind pattern")
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"train_winds: wind pattern name {dup[0]!r} is used twice")
        elif self.train_winds or self.heldout_winds:
            raise ValueError("train_winds: wind patterns are for scene 'flag' (the cape's sequences are "
                             "character.train_clips / heldout_clips)")
        if self.append_pose and self.scene != "cape":
            raise ValueError("append_pose: only the cape has a body whose pose can be appended")
        if self.rows * self.cols > L.MAX_VERTICES:
            raise ValueError(f"rows: rows x cols = {self.rows * self.cols} vertices, at most {L.MAX_VERTICES}")
        return self

    @property
    def size(self) -> tuple[float, float]:
        """``(width, height)`` in metres (scene defaults where unset)."""
        w0, h0 = (0.46, 0.8) if self.scene == "cape" else (1.2, 0.8)
        return (self.width or w0, self.height or h0)

    def simulation_key(self) -> dict[str, object]:
        """What changes the simulated positions (not ``append_pose``, how they are read, nor ``workers``)."""
        return self.model_dump(mode="json", exclude={"append_pose", "workers"})
