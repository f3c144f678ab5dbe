"""The character's material in the Python player: its base colour (per vertex and per pixel) and its RPO (numpy only).

Base colour (glTF ``baseColorFactor`` times the sRGB texture through ``TEXCOORD_0``, :mod:`prt_torch.rig.material`)
multiplies the LINEAR radiance before the tone map.

* Per vertex (:func:`vertex_base_color`): the texture sampled at every triangle corner and averaged per vertex.
  :meth:`prt_torch.player.player.Player.colors` uses it (its ``(V, 3)`` colours, the tone map it fixes), and so does
  a window (interactive play) and a textured mesh's silhouette pixels.
* Per pixel (:func:`surface_texture`, the offscreen images of a textured character): the renderer computes
  ``tonemap(interp(L) * factor * texture(interp(uv)))`` for every pixel of the character
  (:class:`prt_torch.player.render.MeshRenderer`), as the browser player's fragment shader does.

RPO (:func:`select_rpo`): ``material`` is a BRDF name beside the run's catalogue: the material's Cook-Torrance RPO
(:func:`prt_torch.rig.material.material_brdf`), built once and cached in the run's RPO directory
(:func:`prt_torch.rig.material.material_rpo_file`). It is the default BRDF of a character that has its own material
(a glTF character); the built-in character has none (:data:`~prt_torch.rig.material.DEFAULT_MATERIAL`: white,
roughness 0.5, dielectric) and keeps the run's first catalogue BRDF by default.

The look (:func:`surface_albedo`, a :class:`SurfaceAlbedo`): both rules above in one object, the ONE albedo rule
of everything that shows or scores a character's surface: the player (:meth:`~prt_torch.player.player.Player.
surface_radiance`, its renderer) and ``prt compare`` (every row of its strip, the Monte-Carlo reference included,
and every PSNR: :class:`prt_torch.scoring.images.ImageRenderer`, :func:`prt_torch.scoring.rpos.player_brdfs`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, warn
from prt_torch.rig.material import (
    MATERIAL_BRDF,
    character_material,
    corner_to_vertex_mean,
    linear_texture,
    material_rpo_file,
    sample_texture,
)


def vertex_base_color(character: Any) -> np.ndarray | None:
    """``(V, 3)`` float32 linear base colour per vertex, or ``None`` when it is white everywhere (the
    default material: the radiance is used as it is)."""
    m = character_material(character)
    factor = np.asarray(m.base_color[:3], dtype=np.float64)
    uv = getattr(character, "uv", None)
    if m.texture is None or uv is None:
        if np.all(factor == 1.0):
            return None
        return np.broadcast_to(factor.astype(np.float32), (character.num_vertices, 3)).copy()
    corner = sample_texture(m.texture, uv)  # (T, 3, 3) linear RGB
    base = corner_to_vertex_mean(corner, character.faces, character.num_vertices) * factor
    return np.ascontiguousarray(base, dtype=np.float32)


def surface_texture(character: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """``(uv (T, 3, 2) float32, base (H, W, 3) float32)``: a textured character's per-corner texture coordinates and
    its LINEAR base colour texture times the factor (what :class:`~prt_torch.player.render.MeshRenderer` shades per
    pixel with), or ``None`` without a texture or UVs."""
    m = character_material(character)
    uv = getattr(character, "uv", None)
    if m.texture is None or uv is None:
        return None
    base = linear_texture(m.texture) * np.asarray(m.base_color[:3], dtype=np.float32)
    return np.asarray(uv, dtype=np.float32), np.ascontiguousarray(base, dtype=np.float32)


@dataclass(frozen=True, eq=False)
class SurfaceAlbedo:
    """A character's base colour as the player applies it: ``vertex (V, 3)`` float32 linear per vertex
    (:func:`vertex_base_color`; ``None``: white, the radiance is used as it is) and, for a textured character,
    ``uv (T, 3, 2)`` and the linear ``texture (H, W, 3)`` times the factor (:func:`surface_texture`) that rendered
    images shade with per pixel (``None`` both: per-vertex colours only)."""

    vertex: np.ndarray | None
    uv: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def white(self) -> bool:
        """No base colour at all: every figure and image is the radiance's own."""
        return self.vertex is None and self.texture is None

    def apply(self, radiance: np.ndarray) -> np.ndarray:
        """The surface radiance ``(..., V, 3)``: ``radiance (..., V, 3)`` times the per-vertex base colour (what
        the player tone-maps per vertex; the very array when :attr:`white`)."""
        return radiance if self.vertex is None else radiance * self.vertex

    def summary(self) -> str:
        """One line saying which base colour multiplies the radiance."""
        if self.texture is not None:
            return ("glTF base-colour texture x factor: per pixel in images (interior pixels), per vertex (the "
                    "corner mean) in vertex figures and silhouette pixels")
        if self.vertex is not None:
            return f"base colour factor {np.round(self.vertex[0].astype(float), 4).tolist()} (no texture)"
        return "white (no base colour)"


def surface_albedo(character: Any) -> SurfaceAlbedo:
    """The :class:`SurfaceAlbedo` of ``character`` (its material; the default material's is white)."""
    tex = surface_texture(character)
    return SurfaceAlbedo(vertex_base_color(character), None if tex is None else tex[0],
                         None if tex is None else tex[1])


def has_own_material(character: Any) -> bool:
    """Whether ``character`` has its own material (a glTF character): then ``material`` is the BRDF it plays."""
    return getattr(character, "material", None) is not None


# -- the material's RPO ------------------------------------------------------------------------------------------


def brdf_names(bundle: Any) -> list[str]:
    """The BRDFs a run can be played with: its RPO catalogue, then ``material``."""
    return [*bundle.brdf_names, MATERIAL_BRDF]


def default_brdf(bundle: Any, material: bool = True) -> str:
    """``material`` for a character with its own material (a glTF character), else the catalogue's first BRDF
    (``material=False``: a renderer that shades catalogue BRDFs only; the catalogue's first for every character)."""
    own = material and has_own_material(bundle.character)
    return MATERIAL_BRDF if own else bundle.brdf_names[0]


def material_rpo(bundle: Any, build: bool = True) -> Any:
    """The character material's RPO as :class:`~prt_torch.player.bundle.RPOTensors` (the run's SH order and
    shading-graph terms), from the run's cache, built there on first use (``build=False``: ``None`` instead)."""
    from prt_torch.player.bundle import load_rpo_tensors

    path = material_rpo_file(character_material(bundle.character), bundle.order, bundle.n_terms, run=bundle.run,
                             build=build)
    return None if path is None else load_rpo_tensors(path, bundle.order, bundle.n_terms)


def select_rpo(bundle: Any, name: str | None = None, material: bool = True) -> Any:
    """The RPO to play: ``name`` from the run's catalogue, an RPO ``.npz`` file, or ``material``; ``None``:
    :func:`default_brdf` (``material``: as there; when the default is ``material`` and it can be neither loaded nor
    built - a player-only install without scikit-learn - the catalogue's first BRDF, with a warning)."""
    if name is None:
        name = default_brdf(bundle, material)
        if name == MATERIAL_BRDF:
            try:
                return material_rpo(bundle)
            except PrtError as exc:
                warn(f"{exc}; playing {bundle.brdf_names[0]!r} instead")
                return bundle.rpo(bundle.brdf_names[0])
    if str(name) == MATERIAL_BRDF:
        return material_rpo(bundle)
    key = str(name)
    if key not in bundle.brdf_names and not (key.endswith(".npz") and Path(key).is_file()):
        raise PrtError(f"unknown BRDF {key!r}: this run has {brdf_names(bundle)} (or pass an RPO .npz file)")
    return bundle.rpo(key)
