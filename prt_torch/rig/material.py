"""A character's own material: glTF 2.0 ``pbrMetallicRoughness`` reduced to what PRT shading uses (numpy only).

* **Base colour** ``factor (4,)`` (linear RGBA, glTF ``baseColorFactor``) times the optional sRGB
  ``texture (H, W, 3|4) uint8`` read through ``TEXCOORD_0`` multiplies the shaded radiance (per pixel in the
  browser player, per vertex in the Python player: :func:`prt_torch.player.material.vertex_base_color`).
  UVs are kept per triangle corner, ``Character.uv (T, 3, 2)``, because the loader welds vertices on
  position and skin only (a UV seam would otherwise smear the texture).
* **Roughness / metallic** select the RPO: Cook-Torrance (GGX, ``alpha = roughness^2``) with
  ``f0 = 0.04 + 0.96 metallic``, specular weight ``ks = 0.25 + 0.75 metallic`` and a Lambert part ``kd = 1 - ks``
  (:func:`material_brdf`), built once per (BRDF, order, k) with :func:`prt_torch.brdf.build_rpo` and cached,
  content-addressed, in the run's RPO directory (:func:`material_rpo_file`; building needs scikit-learn: the
  ``export`` extra). Both players know it as the BRDF ``material`` (:data:`MATERIAL_BRDF`); the Python player
  plays it by default for a character that has its own material (:func:`prt_torch.player.material.select_rpo`).

The built-in character gets :data:`DEFAULT_MATERIAL` (white, roughness 0.5, dielectric), which leaves the
player's images as they were before materials existed. A character without a material (an older
``character.npz``) behaves as if it had the default.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import DamagedArtifact, PrtError, StaleArtifact, check

#: specular share of a dielectric (metallic = 0) material; metals are all specular
SPECULAR_WEIGHT = 0.25

#: roughness range the Cook-Torrance BRDF accepts (prt_torch.brdf.CookTorrance)
ROUGHNESS_RANGE = (0.02, 1.0)


@dataclass(frozen=True, eq=False)
class Material:
    """``base_color (4,)`` linear RGBA factor, ``metallic``, ``roughness`` in [0, 1], optional sRGB
    ``texture (H, W, 3|4) uint8`` (row 0 = the top of the image = ``v = 0``), and a ``name``."""

    name: str = "default"
    base_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    metallic: float = 0.0
    roughness: float = 0.5
    texture: np.ndarray | None = None

    def __post_init__(self) -> None:
        bc = np.asarray(self.base_color, dtype=np.float64).reshape(-1)
        check(bc.shape == (4,) and bool(np.isfinite(bc).all()) and bool((bc >= 0).all()),
              f"material {self.name!r}: base colour factor must be 4 finite numbers >= 0, got {self.base_color}")
        object.__setattr__(self, "base_color", tuple(float(x) for x in bc))
        for key in ("metallic", "roughness"):
            x = float(getattr(self, key))
            check(np.isfinite(x) and 0.0 <= x <= 1.0, f"material {self.name!r}: {key} must be in [0, 1], got {x}")
            object.__setattr__(self, key, x)
        if self.texture is not None:
            t = np.asarray(self.texture)
            check(t.dtype == np.uint8 and t.ndim == 3 and t.shape[2] in (3, 4) and t.shape[0] > 0 and t.shape[1] > 0,
                  f"material {self.name!r}: texture must be (H, W, 3|4) uint8, got {t.dtype} {t.shape}")
            object.__setattr__(self, "texture", np.ascontiguousarray(t))

    def summary(self) -> dict[str, Any]:
        """JSON-able scalars (no texture pixels)."""
        return {"name": self.name, "base_color": list(self.base_color), "metallic": self.metallic,
                "roughness": self.roughness, "has_texture": self.texture is not None}

    def to_json(self) -> str:
        d = self.summary()
        d.pop("has_texture")
        return json.dumps(d, sort_keys=True)

    @classmethod
    def from_json(cls, text: str, texture: np.ndarray | None = None) -> Material:
        try:
            d = json.loads(text)
        except ValueError as exc:
            raise PrtError(f"bad material record ({exc})") from None
        check(isinstance(d, dict), "bad material record: not an object")
        return cls(str(d.get("name", "material")), tuple(d.get("base_color", (1, 1, 1, 1))),
                   float(d.get("metallic", 0.0)), float(d.get("roughness", 0.5)), texture)


#: the built-in character's material (and that of any character without one)
DEFAULT_MATERIAL = Material()


def character_material(character: Any) -> Material:
    """The character's material, or :data:`DEFAULT_MATERIAL` when it has none."""
    m = getattr(character, "material", None)
    return m if isinstance(m, Material) else DEFAULT_MATERIAL


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (the IEC 61966-2-1 curve)."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_texture(texture: np.ndarray) -> np.ndarray:
    """An sRGB ``texture (H, W, 3|4) uint8`` -> its LINEAR RGB ``(H, W, 3)`` float32 (alpha dropped)."""
    return srgb_to_linear(np.asarray(texture)[..., :3] / 255.0).astype(np.float32)


def sample_linear(t: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeat-wrapped lookup of a float texture ``t (H, W, D)`` at ``uv (..., 2)`` (glTF convention:
    ``u`` right, ``v`` down from the top row; texel centres at half-integers). Returns ``(..., D)`` float32."""
    h, w = t.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    check(uv.shape[-1] == 2 and bool(np.isfinite(uv).all()), f"texture coordinates must be finite (..., 2), "
                                                             f"got {uv.shape}")
    x = uv[..., 0] * w - 0.5
    y = uv[..., 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xs, xs1 = np.mod(x0, w), np.mod(x0 + 1, w)
    ys, ys1 = np.mod(y0, h), np.mod(y0 + 1, h)
    top = t[ys, xs] * (1 - fx) + t[ys, xs1] * fx
    bot = t[ys1, xs] * (1 - fx) + t[ys1, xs1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float32)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear, repeat-wrapped lookup of an sRGB ``texture (H, W, 3|4) uint8`` at ``uv (..., 2)`` (glTF
    convention, :func:`sample_linear`), filtered in LINEAR space. Returns linear RGB ``(..., 3)`` float32."""
    return sample_linear(linear_texture(texture), uv)


def corner_to_vertex_mean(corner: np.ndarray, faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Average per-corner values ``(T, 3, D)`` onto vertices ``(V, D)`` (vertices in no face get 1)."""
    faces = np.asarray(faces, dtype=np.int64)
    corner = np.asarray(corner, dtype=np.float64)
    d = corner.shape[-1]
    acc = np.zeros((n_vertices, d))
    np.add.at(acc, faces.reshape(-1), corner.reshape(-1, d))
    cnt = np.bincount(faces.reshape(-1), minlength=n_vertices).astype(np.float64)[:, None]
    return np.where(cnt > 0, acc / np.maximum(cnt, 1.0), 1.0)


def material_brdf(material: Material) -> Any:
    """The material's BRDF: :class:`prt_torch.brdf.CookTorrance` (GGX) with its roughness (clamped to the
    BRDF's range), ``f0 = 0.04 + 0.96 metallic``, specular weight ``ks = w + (1 - w) metallic`` with
    ``w =`` :data:`SPECULAR_WEIGHT`, Lambert part ``kd = 1 - ks`` (energy: ``kd + ks = 1``)."""
    from prt_torch.brdf import CookTorrance

    r = float(np.clip(material.roughness, *ROUGHNESS_RANGE))
    ks = SPECULAR_WEIGHT + (1.0 - SPECULAR_WEIGHT) * material.metallic
    return CookTorrance(roughness=r, f0=0.04 + 0.96 * material.metallic, kd=1.0 - ks, ks=ks, name="material")


#: the BRDF name the material's RPO is known by (``prt play --brdf material``, the browser player's catalogue)
MATERIAL_BRDF = "material"


def analytic_brdf(name: str, material: Material | None = None) -> Any:
    """The analytic BRDF an RPO named ``name`` was built from (the peak lights' direct term uses it): ``material``
    (:data:`MATERIAL_BRDF`, with the character's ``material``) -> :func:`material_brdf`, a catalogue name ->
    :func:`prt_torch.brdf.rpo.builtin_brdf`; ``None`` for an RPO of no known BRDF."""
    from prt_torch.brdf.rpo import CATALOGUE, builtin_brdf

    if name == MATERIAL_BRDF and material is not None:
        return material_brdf(material)
    return builtin_brdf(name) if name in CATALOGUE else None


def material_rpo_key(material: Material, order: int, k: int) -> str:
    """Content address of the material's RPO: sha256 (first 16 hex digits) of the RPO file format, the BRDF
    (:func:`material_brdf`, all its parameters), ``order``, ``k``, the factorisation's hemisphere rule and its
    default factorisation order (:func:`prt_torch.brdf.rpo.rpo_key_text`). Two materials with the same roughness and
    metallic share it (the base colour does not enter the RPO)."""
    from prt_torch.brdf.rpo import rpo_key_text

    return hashlib.sha256(rpo_key_text(material_brdf(material), order, k).encode()).hexdigest()[:16]


def material_rpo_file(material: Material, order: int, k: int, run: Any = None,
                      cache_dir: str | os.PathLike[str] | None = None, build: bool = True) -> Path | None:
    """Path of the material's RPO (SH ``order``, ``k`` terms): :func:`prt_torch.brdf.build_rpo` of
    :func:`material_brdf`, built on first use and cached, content-addressed (:func:`material_rpo_key`), in the
    run's RPO directory (``run``: a :class:`prt_torch.rundir.RunDir` or path; the file is
    :meth:`~prt_torch.rundir.RunDir.material_rpo_path`) or else in ``cache_dir`` (default
    :func:`prt_torch.brdf.rpo.default_cache_dir`). A run directory that cannot be written falls back to the
    cache directory. ``build=False``: ``None`` instead of building a missing one.

    Building factors the BRDF table with scikit-learn's randomized SVD (the ``export`` extra, about 2 s); a
    player-only install without it gets a one-line :class:`PrtError`.
    """
    from prt_torch.brdf.rpo import RPO, default_cache_dir
    from prt_torch.rundir import RunDir

    key = material_rpo_key(material, order, k)
    fallback = (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / f"{MATERIAL_BRDF}-{key}.npz"
    places = ([RunDir.of(run).material_rpo_path(key)] if run is not None else []) + [fallback]
    for path in places:
        if path.is_file():
            try:
                RPO.load(path)
                return path
            except (StaleArtifact, DamagedArtifact):
                pass  # damaged cache entry: rebuilt below
    if not build:
        return None
    try:
        import sklearn  # noqa: F401
    except ImportError:
        raise PrtError(f"building the material's RPO (Cook-Torrance, roughness {material.roughness:g}) needs "
                       f"scikit-learn: pip install 'prt-torch[export]', or play with --brdf NAME") from None
    from prt_torch.brdf.rpo import build_rpo

    rpo = build_rpo(material_brdf(material), order=order, k=k, name=MATERIAL_BRDF)
    for path in places:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            rpo.save(path)  # atomic
            return path
        except OSError:
            continue  # a read-only run directory: the user cache
    raise PrtError(f"cannot write the material's RPO to {places[-1]} (nor to the run directory)")
