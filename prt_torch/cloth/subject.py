"""The subject of a cloth run: the cloth sheet (flag), or the built-in body with a cape (cape), as one mesh.

Vertex order of the subject: the body's vertices first (cape only), then the cloth's, row-major over the
``rows x cols`` grid (:mod:`prt_torch.cloth.config`). Faces: the body's, then the cloth's, counter-clockwise
seen from the cloth's outside (+y at rest: away from the cape's body, the flag's side the default wind blows
toward). Saved by the bake as a single-root-joint :class:`~prt_torch.rig.character.Character` (every skin
weight 1 on joint ``root``, identity bind), so every reader of ``character.npz`` keeps working; per-frame
positions come from the vertex cache (:mod:`prt_torch.cloth.cache`), never from skinning.

Pinned vertices: the flag's pole column (``c = 0``), fixed in place; the cape's top row (``r = 0``), carried
rigidly by the anchor joint (:func:`prt_torch.cloth.body.anchor_joint`, the chest of a humanoid).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from prt_torch.cloth.body import Capsules, anchor_joint, cape_rest, fit_capsules
from prt_torch.cloth.config import ClothConfig, WindPattern
from prt_torch.errors import PrtError, check
from prt_torch.rig.character import Character, Poses

if TYPE_CHECKING:
    from prt_torch.config import RunConfig

SPLITS = ("train", "heldout")


def grid_faces(rows: int, cols: int) -> np.ndarray:
    """``(2 (rows-1)(cols-1), 3)`` int64 triangles of a row-major ``rows x cols`` vertex grid; with rows going
    down and columns going right (+x), the normals point toward +y."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def single_joint_character(name: str, vertices: np.ndarray, faces: np.ndarray) -> Character:
    """A rigid single-root-joint character (identity bind, every weight 1) holding a mesh."""
    from prt_torch.rig.mesh import vertex_normals

    v = len(vertices)
    eye = np.eye(4)[None]
    return Character(name=name, joint_names=["root"], parents=np.array([-1]), bind_local=eye, inverse_bind=eye,
                     rest_vertices=np.asarray(vertices, np.float32), rest_normals=vertex_normals(vertices, faces),
                     faces=np.asarray(faces, np.int64), joints=np.zeros((v, 1), np.int64),
                     weights=np.ones((v, 1), np.float32))


@dataclass
class BodySequence:
    """The cape's driving motion of one sequence: the body's :class:`Poses` (``T`` frames at the cloth fps)."""

    name: str
    poses: Poses


@dataclass
class ClothSubject:
    """A cloth (and, for the cape, its body). Build with :meth:`load` (from a run config) or directly.

    Attributes:
        cloth: the cloth section of the config.
        cloth_rest: ``(N, 3)`` float64 rest vertices of the cloth (row-major grid).
        cloth_faces: ``(M, 3)`` int64 cloth triangles in CLOTH indices.
        pinned: ``(P,)`` int64 pinned cloth vertices (cloth indices).
        fps: output frames per second.
        body: the cape's skinned character (``None`` for the flag).
        capsules: the body's colliders (``None`` for the flag).
        anchor: the joint carrying the pinned row (cape), else -1.
        splits: ``{"train": [...], "heldout": [...]}`` sequence names.
        body_clips: cape: sequence name -> :class:`prt_torch.rig.clip.Clip` (its frames at ``fps``).
        winds: flag: sequence name -> :class:`WindPattern`.
    """

    cloth: ClothConfig
    cloth_rest: np.ndarray
    cloth_faces: np.ndarray
    pinned: np.ndarray
    fps: float
    body: Character | None = None
    capsules: Capsules | None = None
    anchor: int = -1
    splits: dict[str, list[str]] = field(default_factory=lambda: {"train": [], "heldout": []})
    body_clips: dict = field(default_factory=dict)
    winds: dict[str, WindPattern] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from prt_torch.deform.mesh import check_deformable_mesh

        self.cloth_rest = np.asarray(self.cloth_rest, dtype=np.float64)
        self.cloth_faces = np.asarray(self.cloth_faces, dtype=np.int64)
        check_deformable_mesh(self.cloth_rest, self.cloth_faces, "cloth")
        self.pinned = np.asarray(self.pinned, dtype=np.int64).reshape(-1)
        check(bool(np.all((self.pinned >= 0) & (self.pinned < len(self.cloth_rest)))),
              f"pinned cloth vertices must lie in [0, {len(self.cloth_rest)})")
        check(len(np.unique(self.pinned)) < len(self.cloth_rest), "every cloth vertex is pinned: nothing to simulate")
        check(self.body is None or self.capsules is not None, "a body needs its colliders")

    # -- construction ------------------------------------------------------------------------------
    @classmethod
    def load(cls, cfg: RunConfig) -> ClothSubject:
        """The subject of a run config with a ``cloth:`` section (deterministic)."""
        c: ClothConfig | None = getattr(cfg, "cloth", None)
        if c is None:
            raise PrtError(f"config {cfg.name!r} has no cloth section")
        width, height = c.size
        faces = grid_faces(c.rows, c.cols)
        if c.scene == "flag":
            x, z = np.meshgrid(np.linspace(0.0, width, c.cols), c.flag_top - np.linspace(0.0, height, c.rows))
            rest = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
            pinned = np.arange(c.rows) * c.cols if c.pin_edge else np.zeros(0, np.int64)
            fps = c.fps or cfg.character.fps
            splits = {"train": [w.name for w in c.train_winds], "heldout": [w.name for w in c.heldout_winds]}
            return cls(c, rest, faces, pinned, fps, splits=splits,
                       winds={w.name: w for w in c.train_winds + c.heldout_winds})
        from prt_torch.rig.load import check_disjoint, load_character, resolve_clips

        fps = cfg.character.fps
        if c.fps is not None and c.fps != fps:
            raise PrtError(f"cloth.fps={c.fps:g}: the cape is sampled at character.fps={fps:g} (leave cloth.fps unset)")
        body = load_character(cfg)
        train = resolve_clips(body, cfg.character.train_clips, fps, "train_clips")
        held = resolve_clips(body, cfg.character.heldout_clips, fps, "heldout_clips")
        check_disjoint(train, held)
        if not train:
            raise PrtError("the cape needs character.train_clips (the body motions that drive it)")
        capsules = fit_capsules(body)
        rest = cape_rest(body, capsules, c.rows, c.cols, width, height, c.radius + c.collider_gap)
        return cls(c, rest, faces, np.arange(c.cols), fps, body=body, capsules=capsules, anchor=anchor_joint(body),
                   splits={"train": [p.name for p in train], "heldout": [p.name for p in held]},
                   body_clips={p.name: p.clip for p in train + held})

    # -- the subject mesh ----------------------------------------------------------------------------
    @property
    def n_body(self) -> int:
        """Body vertices in front of the cloth's (0 for the flag)."""
        return 0 if self.body is None else self.body.num_vertices

    @property
    def cloth_slice(self) -> slice:
        """The cloth's vertex range in the subject."""
        return slice(self.n_body, self.n_body + len(self.cloth_rest))

    @property
    def n_vertices(self) -> int:
        return self.n_body + len(self.cloth_rest)

    @cached_property
    def character(self) -> Character:
        """The single-root-joint subject: rest = body rest + cloth rest, faces = body faces + cloth faces."""
        if self.body is None:
            return single_joint_character(f"cloth:{self.cloth.scene}", self.cloth_rest, self.cloth_faces)
        verts = np.concatenate([self.body.rest_vertices.astype(np.float64), self.cloth_rest])
        faces = np.concatenate([self.body.faces, self.cloth_faces + self.n_body])
        ch = single_joint_character(f"cloth:{self.cloth.scene}", verts, faces)
        ch.material = self.body.material
        return ch

    @cached_property
    def cloth_edges(self) -> np.ndarray:
        """``(E, 4)`` int64 interior edges ``(i, j, k, l)`` of the cloth in SUBJECT vertex indices
        (:func:`prt_torch.deform.mesh.interior_edges`)."""
        from prt_torch.deform.mesh import interior_edges

        return np.asarray(interior_edges(self.cloth_faces), dtype=np.int64) + self.n_body

    @cached_property
    def unique_edges(self) -> np.ndarray:
        """``(E', 2)`` int64 every edge of the cloth once (cloth indices), for the stretch check."""
        e = np.sort(self.cloth_faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        return np.unique(e, axis=0)

    def sequences(self, split: str) -> list[str]:
        """The sequence names of ``split`` (``"train"`` or ``"heldout"``), in config order."""
        check(split in SPLITS, f"unknown split {split!r}: expected one of {list(SPLITS)}")
        return list(self.splits[split])

    def all_sequences(self) -> list[str]:
        return [*self.splits["train"], *self.splits["heldout"]]

    def body_sequence(self, name: str) -> BodySequence:
        """The cape's body motion of sequence ``name``."""
        check(self.body is not None and name in self.body_clips, f"unknown cape sequence {name!r}")
        assert self.body is not None
        return BodySequence(name, self.body.pose(self.body_clips[name]))

    def n_frames(self, name: str) -> int:
        """Recorded frames of sequence ``name``."""
        if self.body is not None:
            check(name in self.body_clips, f"unknown cape sequence {name!r}")
            return int(self.body_clips[name].num_frames)
        check(name in self.winds, f"unknown flag sequence {name!r}")
        return int(self.winds[name].frames)
