"""Shading and images on the shipping path: the one rule ``prt eval`` and ``prt compare`` both score with.

What ships (``prt export`` + ``prt play``) and therefore what is scored here:

* **BRDFs**: the RPO catalogue of :func:`prt_torch.brdf.rpo.builtin_rpo` (``lambert``; ``phong`` =
  exponent 16, kd 0.3, ks 0.7; ``k = 8`` terms), read from the run's exported ``rpo/<name>.npz`` when the
  run is exported (the very files the player loads), else built by the same function (:func:`shipping_rpos`).
* **Shading**: seed 003 eq. 11 through :func:`prt_torch.shade.shade_rpo` (torch, ``fused``), with
  ``L = tint * sum_b (w_b . y(wo)) (l . M_b v)`` in each vertex frame; ``wo`` is the unit direction from
  the vertex to the player's camera, expressed in the frame (no clamp below the horizon: the exported
  shading graph has none either). Vectorised over frames and vertices, chunked over frames
  (:class:`ShippingShader`, at most ``max_rows`` vertex-frames per torch call).
* **Lighting**: the player's (:func:`prt_torch.player.lighting.load_lighting`): the SH of the environment
  (order of the run) multiplied by the player's sinc window, then ``K = 3`` ZH lobes fitted to that
  *windowed* SH. Two lighting paths are reported side by side:

  - ``exact``: the windowed SH ``Lighting.sh (C, 3)`` rotated into every vertex frame exactly with the
    SH rotation blocks of :func:`prt_torch.sh.rotation.sh_rotation_blocks` (``l_local = D(F) l``). This
    is the best any order-``n`` SH shading of that lighting can do: no lobe fit.
  - ``lobes``: the ZH lobes the player ships, rotated into the frames with
    :func:`prt_torch.shade.lobes.rotate_lobes_to_frames` (what ``shading.onnx`` computes).

  Both use the same windowed SH, so ``lobes`` vs ``exact`` isolates the error of the 3-lobe fit.
  Frames are orthonormalised once (polar factor, float64) and shared by both paths.
* **Lights**: ``sky`` = the player's default procedural sun + sky (``load_lighting(None, order)``), and
  ``uffizi`` / ``mondello`` from ``../shared/data/envmaps`` when present (:func:`shipping_lights`).
* **Images**: the player's camera (:func:`player_camera`: :attr:`prt_torch.player.Player.eye` rule and
  its window size), its :class:`~prt_torch.player.render.MeshRenderer` and its tone map
  (:func:`~prt_torch.player.tonemap.auto_tonemap`), fixed ONCE per frame from the truth radiance and applied
  to every prediction of that frame. PSNR (:func:`image_psnr`) is ``10 log10(1 / MSE)`` over the colours in
  ``[0, 1]`` (the rendered 8-bit image / 255) of the character's pixels only: the mask holds the pixels
  *fully* covered by the mesh (a render with white vertex colours on a black background reads 255 in every
  channel; anti-aliased silhouette pixels, which mix in the background, are excluded).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import check
from prt_torch.metrics import evenly_spaced_indices, psnr_from_mse
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

    from prt_torch.brdf.rpo import RPO
    from prt_torch.player.lighting import Lighting
    from prt_torch.rundir import RunDir

#: shipped BRDFs scored by eval/compare: (diffuse, glossy)
DIFFUSE, GLOSSY = "lambert", "phong"
BRDFS: tuple[str, ...] = (DIFFUSE, GLOSSY)
#: lighting paths (see the module docstring)
PATHS: tuple[str, ...] = ("exact", "lobes")
#: the player's default light (procedural sun + sky)
PLAYER_LIGHT = "sky"
#: optional environment maps under ``<shared data>/envmaps``
ENVMAPS = {"uffizi": "uffizi.hdr", "mondello": "spiaggia_di_mondello_1k.hdr"}
#: BRDF terms of the shipped RPOs (``prt export``'s ``n_terms``)
N_TERMS = 8
#: the player's default window ``(H, W)`` (``Player(window_size=...)``)
WINDOW_HW = (480, 640)


def shared_data_dir() -> Path | None:
    """``$PRT_SHARED/data`` or ``../shared/data`` next to the repository (or the working directory), when present."""
    env = os.environ.get("PRT_SHARED")
    cands = [Path(env) / "data"] if env else []
    cands.append(Path(__file__).resolve().parents[2].parent / "shared" / "data")
    cands.append(Path.cwd().parent / "shared" / "data")
    return next((c for c in cands if c.is_dir()), None)


def shipping_lights(order: int, shared_data: Path | None = None, names: Sequence[str] | None = None,
                    n_lobes: int = 3) -> dict[str, Lighting]:
    """The player's lightings by name: ``sky`` (its default) plus the env maps of :data:`ENVMAPS` found under
    ``shared_data/envmaps`` (skipped when absent). ``names`` restricts the set (unknown names: PrtError)."""
    from prt_torch.player.lighting import load_lighting

    known = [PLAYER_LIGHT, *ENVMAPS]
    for n in names or ():
        check(n in known, f"unknown light {n!r}: expected one of {known}")
    want = list(names) if names else known
    out: dict[str, Lighting] = {}
    for name in want:
        if name == PLAYER_LIGHT:
            out[name] = load_lighting(None, order, n_lobes)
            continue
        path = Path(shared_data) / "envmaps" / ENVMAPS[name] if shared_data is not None else None
        if path is not None and path.is_file():
            out[name] = load_lighting(path, order, n_lobes)
    return out


def shipping_rpos(order: int, run: RunDir | None = None, names: Sequence[str] = BRDFS,
                  n_terms: int = N_TERMS) -> dict[str, RPO]:
    """The shipped RPOs by name: the run's exported ``rpo/<name>.npz`` when the export lists it (verified
    against the export's hashes, what the player loads), else :func:`prt_torch.brdf.rpo.builtin_rpo` (what
    ``prt export`` writes) of ``order`` and ``n_terms``."""
    from prt_torch.brdf.rpo import RPO, builtin_rpo

    exported: set[str] = set()
    if run is not None and run.export_json.is_file():
        exported = set(run.export_meta().get("rpo_files", {}))  # export_meta verifies every file's sha256
    out = {}
    for name in names:
        path = run.rpo_path(name) if run is not None and name in exported else None
        rpo = RPO.load(path) if path is not None and path.is_file() else builtin_rpo(name, order=order, k=n_terms)
        check(rpo.order == order, f"RPO {name!r} has order {rpo.order}, the run {order}")
        out[name] = rpo
    return out


def unshadowed_visibility(order: int, below_horizon: str | Mapping[str, Any] | None = "zero") -> np.ndarray:
    """``(C,)`` float32: the player's unshadowed visibility in the dataset's convention: the SH of the
    upper-hemisphere indicator (``"zero"``) or the constant 1 (``"one"``).

    ``below_horizon``: the convention, or a dataset's attributes / ``attrs["bake"]`` dict (missing: ``"zero"``).
    """
    from prt_torch.bake.store import below_horizon_of
    from prt_torch.player.lighting import hemisphere_visibility

    if below_horizon is None or isinstance(below_horizon, Mapping):
        below_horizon = below_horizon_of(dict(below_horizon or {}))
    return hemisphere_visibility(order, below_horizon)


def orthonormal_frames(frames: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> float64 nearest rotations (polar factor ``U V^T`` of the SVD; det +1)."""
    f = np.asarray(frames, dtype=np.float64)
    check_shape(f, "... 3 3", name="frames")
    check(bool(np.isfinite(f).all()), "frames contain NaN or Inf")
    u, _, vt = np.linalg.svd(f)
    r = u @ vt
    flip = np.linalg.det(r) < 0  # not expected for right-handed frames; keep a proper rotation anyway
    if flip.any():
        u[flip, :, 2] *= -1
        r[flip] = u[flip] @ vt[flip]
    return r


def local_lighting(lighting: Lighting, frames: torch.Tensor, path: str) -> torch.Tensor:
    """Local-frame SH lighting ``(N, C, 3)`` of a player :class:`Lighting` at ``frames (N, 3, 3)`` (torch,
    rotations, rows t, b, n), by lighting ``path`` (``exact``: ``D(F) sh``; ``lobes``: the ZH lobes)."""
    import torch

    from prt_torch.sh.basis import order_from_coeffs
    from prt_torch.sh.rotation import sh_rotation_blocks
    from prt_torch.shade.lobes import rotate_lobes_to_frames

    dt = frames.dtype
    if path == "lobes":
        dirs = torch.as_tensor(np.asarray(lighting.dirs, dtype=np.float64))
        dirs = dirs / dirs.norm(dim=-1, keepdim=True)
        return rotate_lobes_to_frames(dirs.to(dt), torch.as_tensor(np.asarray(lighting.coeffs), dtype=dt), frames,
                                      check=False)
    check(path == "exact", f"unknown lighting path {path!r}: expected one of {list(PATHS)}")
    sh = torch.as_tensor(np.asarray(lighting.sh, dtype=np.float64), dtype=dt)  # (C, 3)
    order = order_from_coeffs(sh.shape[0])
    blocks = sh_rotation_blocks(frames, order, check=False)
    return torch.cat([blocks[l] @ sh[l * l:(l + 1) * (l + 1)] for l in range(order)], dim=-2)


Combo = tuple[str, str, str]  # (light, brdf, lighting path)


@dataclass
class ShippingShader:
    """Shades several visibilities at once on the shipping path (see the module docstring).

    Args:
        lights: ``{name: Lighting}`` (:func:`shipping_lights`).
        rpos: ``{name: RPO}`` (:func:`shipping_rpos`).
        eye: ``(3,)`` world camera position (the view directions point from each vertex to it).
        paths: lighting paths to evaluate (subset of :data:`PATHS`).
        dtype: torch dtype of the shading (float32 like the player; float64 for closed-form checks).
        max_rows: at most this many vertex-frames per torch call (memory bound; at least one frame).
    """

    lights: Mapping[str, Lighting]
    rpos: Mapping[str, RPO]
    eye: np.ndarray
    paths: Sequence[str] = PATHS
    dtype: Any = None
    max_rows: int = 1 << 16
    _rpo_t: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        import torch

        from prt_torch.shade.rpo_shading import RPOTensors

        if self.dtype is None:
            self.dtype = torch.float32
        for p in self.paths:
            check(p in PATHS, f"unknown lighting path {p!r}: expected one of {list(PATHS)}")
        check(len(self.lights) > 0 and len(self.rpos) > 0, "shipping shader needs at least one light and one BRDF")
        self.eye = np.asarray(self.eye, dtype=np.float64).reshape(3)
        self._rpo_t = {n: RPOTensors.from_rpo(r, self.dtype) for n, r in self.rpos.items()}

    @property
    def combos(self) -> list[Combo]:
        """Every ``(light, brdf, path)`` this shader produces, in order."""
        return [(ln, bn, p) for ln in self.lights for bn in self.rpos for p in self.paths]

    def chunks(self, n_frames: int, n_vertices: int) -> list[slice]:
        """Frame slices of at most ``max_rows`` vertex-frames (at least one frame each)."""
        step = max(1, self.max_rows // max(n_vertices, 1))
        return [slice(i, min(i + step, n_frames)) for i in range(0, n_frames, step)]

    def shade_chunk(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
                    positions: np.ndarray) -> dict[Combo, dict[str, np.ndarray]]:
        """Radiance of every visibility under every combo for a few frames.

        Args:
            vis: ``{name: (f, V, C)}`` local-frame SH visibilities (a ``(C,)`` or ``(V, C)`` array broadcasts).
            frames: ``(f, V, 3, 3)`` vertex frames (rows t, b, n).
            positions: ``(f, V, 3)`` world positions.

        Returns:
            ``{(light, brdf, path): {name: (f, V, 3) float32}}``.
        """
        import torch

        from prt_torch.shade.rpo_shading import shade_rpo

        frames = np.asarray(frames)
        positions = np.asarray(positions, dtype=np.float64)
        check_shape(frames, "F V 3 3", name="frames")
        f, v = frames.shape[:2]
        check(positions.shape == (f, v, 3), f"positions: expected {(f, v, 3)}, got {positions.shape}")
        rot = orthonormal_frames(frames)  # (f, V, 3, 3) float64
        view = self.eye - positions
        view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-12)
        wo = np.einsum("fvij,fvj->fvi", rot, view)
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        dt = self.dtype
        rot_t = torch.as_tensor(rot.reshape(-1, 3, 3), dtype=dt)
        wo_t = torch.as_tensor(wo, dtype=dt)
        c = next(iter(self._rpo_t.values())).order ** 2
        vis_t = {}
        for name, a in vis.items():
            a = np.asarray(a, dtype=np.float32)
            check(a.shape[-1] == c, f"visibility {name!r}: expected {c} SH coefficients, got shape {a.shape}")
            vis_t[name] = torch.tensor(np.broadcast_to(a, (f, v, c)), dtype=dt)
        out: dict[Combo, dict[str, np.ndarray]] = {}
        with torch.no_grad():
            for ln, light in self.lights.items():
                for p in self.paths:
                    l_local = local_lighting(light, rot_t, p).reshape(f, v, c, 3)
                    for bn, rpo in self._rpo_t.items():
                        out[(ln, bn, p)] = {name: shade_rpo(x, l_local, wo_t, rpo, check=False).numpy()
                                            .astype(np.float32, copy=False) for name, x in vis_t.items()}
        return out

    def shade(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
              positions: np.ndarray) -> Iterator[tuple[slice, dict[Combo, dict[str, np.ndarray]]]]:
        """:meth:`shade_chunk` over frame chunks: yields ``(frame slice, results)`` (``vis`` arrays ``(F, V, C)``,
        or broadcastable ``(C,)``/``(V, C)``; ``frames (F, V, 3, 3)``; ``positions (F, V, 3)``)."""
        f, v = np.asarray(frames).shape[:2]
        for sl in self.chunks(f, v):
            sub = {k: (a[sl] if np.ndim(a) == 3 else a) for k, a in vis.items()}
            yield sl, self.shade_chunk(sub, frames[sl], positions[sl])

    def shade_all(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
                  positions: np.ndarray) -> dict[Combo, dict[str, np.ndarray]]:
        """Every chunk of :meth:`shade` concatenated: ``{combo: {name: (F, V, 3)}}`` (small inputs only)."""
        parts: dict[Combo, dict[str, list[np.ndarray]]] = {}
        for _, res in self.shade(vis, frames, positions):
            for combo, d in res.items():
                for name, a in d.items():
                    parts.setdefault(combo, {}).setdefault(name, []).append(a)
        return {combo: {n: np.concatenate(a) for n, a in d.items()} for combo, d in parts.items()}


@dataclass
class RadianceStats:
    """Streaming vertex-radiance errors of a prediction vs a truth (sums over every entry seen).

    ``radiance_rel_rmse = sqrt(sum (p - t)^2 / sum t^2)`` (:func:`prt_torch.metrics.rel_rmse`) and
    ``psnr_vertex = 10 log10(max(t)^2 / mean (p - t)^2)`` (:func:`prt_torch.metrics.psnr`).
    """

    sse: float = 0.0
    sst: float = 0.0
    n: int = 0
    peak: float = 0.0

    def add(self, pred: np.ndarray, truth: np.ndarray) -> None:
        p, t = np.asarray(pred, dtype=np.float64), np.asarray(truth, dtype=np.float64)
        check(p.shape == t.shape, f"radiance: prediction {p.shape} and truth {t.shape} differ in shape")
        self.sse += float(((p - t) ** 2).sum())
        self.sst += float((t * t).sum())
        self.n += int(t.size)
        self.peak = max(self.peak, float(t.max()) if t.size else 0.0)

    @property
    def rel_rmse(self) -> float:
        return float(np.sqrt(self.sse / max(self.sst, 1e-30)))

    @property
    def psnr(self) -> float:
        return psnr_from_mse(self.sse / max(self.n, 1), self.peak)


@dataclass
class ImageStats:
    """Pooled image error over masked pixels: ``sse`` over colours in [0, 1], ``n`` masked channel values."""

    sse: float = 0.0
    n: int = 0

    def add(self, sse: float, n: int) -> None:
        self.sse += float(sse)
        self.n += int(n)

    @property
    def psnr(self) -> float | None:
        if self.n == 0:
            return None
        return psnr_from_mse(self.sse / self.n)


def image_sse(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """Sum of squared differences of two ``(H, W, 3)`` uint8 images as colours in [0, 1] over ``mask (H, W)``,
    and the number of channel values summed."""
    check(a.shape == b.shape and a.shape[:2] == mask.shape, f"images {a.shape}, {b.shape} and mask {mask.shape}")
    d = (a[mask].astype(np.float64) - b[mask].astype(np.float64)) / 255.0
    return float((d * d).sum()), int(d.size)


def image_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, peak 1.0) of ``(H, W, 3)`` uint8 images ``a`` vs ``b`` over the pixels of ``mask``."""
    sse, n = image_sse(a, b, mask)
    check(n > 0, "image PSNR: the mask is empty (the character is not in view)")
    return psnr_from_mse(sse / n)


@dataclass(frozen=True)
class Camera:
    """The player's camera: ``eye`` and ``center (3,)`` world, window ``(H, W)`` pixels."""

    eye: np.ndarray
    center: np.ndarray
    window_hw: tuple[int, int] = WINDOW_HW


def player_camera(character: Any, window_hw: tuple[int, int] = WINDOW_HW,
                  positions: np.ndarray | None = None) -> Camera:
    """The camera :class:`prt_torch.player.Player` uses for ``character`` at its default azimuth and
    elevation (the player's own :func:`~prt_torch.player.player.camera_target` and
    :func:`~prt_torch.player.player.camera_eye`; no exported run needed). ``positions (F, V, 3)``: a deformable
    sequence, framed as the deformable player frames it (:func:`~prt_torch.player.player.sequence_view`)."""
    from prt_torch.player.player import CAMERA_AZIMUTH, camera_eye, camera_target, sequence_view

    if positions is None:
        (center, radius), azimuth = camera_target(character.rest_vertices), CAMERA_AZIMUTH
    else:
        center, radius, azimuth = sequence_view(positions, character.faces)
    eye = camera_eye(center, radius, azimuth)
    return Camera(np.asarray(eye, dtype=np.float64), np.asarray(center, dtype=np.float64), tuple(window_hw))


class ImageRenderer:
    """The player's :class:`~prt_torch.player.render.MeshRenderer` at the player's camera, plus the mask rule.

    Args:
        rest_vertices: ``(V, 3)``; faces: ``(T, 3)`` of the character.
        camera: :func:`player_camera`.
    """

    BACKGROUND = (0.08, 0.08, 0.1)  # the MeshRenderer default (the player's)

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> None:
        from prt_torch.player.render import MeshRenderer, has_display, quiet_vtk_display_probe

        if not has_display():
            quiet_vtk_display_probe()
        h, w = camera.window_hw
        self.camera = camera
        self.renderer = MeshRenderer(rest_vertices, faces, window_size=(w, h), off_screen=True)
        self.renderer.set_camera(camera.eye, camera.center)
        self.n_vertices = int(np.asarray(rest_vertices).shape[0])
        self._white = np.full((self.n_vertices, 3), 255, np.uint8)

    def render(self, positions: np.ndarray, colors: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 image of the mesh at ``positions (V, 3)`` with vertex ``colors (V, 3)`` uint8."""
        self.renderer.update(np.asarray(positions, dtype=np.float32), colors)
        return self.renderer.render()

    def mask(self, positions: np.ndarray) -> np.ndarray:
        """``(H, W)`` bool: pixels fully covered by the mesh (white vertices on black read 255 everywhere)."""
        pl = self.renderer.plotter
        pl.set_background((0.0, 0.0, 0.0))
        try:
            img = self.render(positions, self._white)
        finally:
            pl.set_background(self.BACKGROUND)
        return (img == 255).all(axis=-1)

    def frame_images(self, positions: np.ndarray, radiance: Mapping[str, np.ndarray], truth: str,
                     mask: np.ndarray | None = None) -> FrameImages:
        """Render every ``radiance[name] (V, 3)`` with ONE tone map fixed from ``radiance[truth]``; images,
        mask and the image SSE of each entry vs the truth."""
        from prt_torch.player.tonemap import auto_tonemap

        tm = auto_tonemap(radiance[truth])
        m = self.mask(positions) if mask is None else mask
        imgs = {name: self.render(positions, tm(np.asarray(r))) for name, r in radiance.items()}
        sse = {name: image_sse(img, imgs[truth], m) for name, img in imgs.items()}
        return FrameImages(imgs, m, sse, tm)

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> ImageRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class FrameImages:
    """One frame's images ``{name: (H, W, 3) uint8}``, its mask ``(H, W)``, ``{name: (sse, n)}`` vs the truth
    and the tone map used (:class:`prt_torch.player.tonemap.ToneMap`)."""

    images: dict[str, np.ndarray]
    mask: np.ndarray
    sse: dict[str, tuple[float, int]]
    tonemap: Any


def image_strip(images: Sequence[np.ndarray], labels: Sequence[str], diffs: Sequence[np.ndarray | None] = (),
                diff_labels: Sequence[str] = (), scale: float = 4.0) -> np.ndarray:
    """A labelled strip: row 1 ``images``; row 2 (when ``diffs`` is given) ``scale x |diff - ref|`` images as
    uint8 (``None`` entries are left black). ``diffs`` entries are ``(img, ref)``-difference images already
    computed by :func:`abs_diff_image`."""
    import cv2

    def lab(img: np.ndarray, text: str) -> np.ndarray:
        img = np.ascontiguousarray(img.copy())
        cv2.putText(img, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (240, 240, 240), 2, cv2.LINE_AA)
        return img

    check(len(images) == len(labels) and len(images) > 0, "image strip: need one label per image")
    row1 = np.concatenate([lab(i, t) for i, t in zip(images, labels, strict=True)], axis=1)
    if not diffs:
        return row1
    blank = np.zeros_like(images[0])
    row2 = np.concatenate([lab(blank if d is None else d, t) for d, t in zip(diffs, diff_labels, strict=True)], axis=1)
    return np.concatenate([row1, row2], axis=0)


def abs_diff_image(img: np.ndarray, ref: np.ndarray, scale: float = 4.0) -> np.ndarray:
    """``scale x |img - ref|`` of two uint8 images, clipped to uint8."""
    d = np.abs(img.astype(np.float32) - ref.astype(np.float32)) * scale
    return np.clip(d + 0.5, 0, 255).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write an ``(H, W, 3)`` uint8 RGB image atomically (the player's PNG writer)."""
    from prt_torch.player.video import write_png as _write

    _write(Path(path), image)
    return Path(path)


def evenly_spaced(n_total: int, n_pick: int, must: Sequence[int] = ()) -> np.ndarray:
    """``min(n_pick, n_total)`` sorted distinct indices in ``[0, n_total)``, evenly spaced, including ``must``."""
    if n_total <= 0 or n_pick <= 0:
        return np.zeros(0, dtype=np.int64)
    base = evenly_spaced_indices(n_total, min(n_pick, n_total))
    idx = np.unique(np.concatenate([base, np.asarray(must, dtype=np.int64)]))
    if len(idx) > n_pick and len(must):
        keep = set(int(m) for m in must)
        extra = [int(i) for i in idx if int(i) not in keep][: max(0, n_pick - len(keep))]
        idx = np.array(sorted(keep | set(extra)), dtype=np.int64)
    return idx
