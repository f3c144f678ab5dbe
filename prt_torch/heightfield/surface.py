"""Animated height-field receivers: the grid, its triangle mesh, normals, vertex frames and two generators.

A height field of size ``N`` is an ``(N, N)`` array ``H[iy, ix]`` of heights (world ``z``) over the square
``[0, extent]^2`` of the ground plane, sampled at ``x = ix * dx``, ``y = iy * dx`` with spacing
``dx = extent / (N - 1)``. Vertex ``v = iy * N + ix`` (row-major, the order of ``H.reshape(-1)``).
Each grid cell is split into two triangles along its ``(ix, iy) -> (ix+1, iy+1)`` diagonal, wound so that
the normals point up (``+z``): ``2 (N - 1)^2`` triangles.

Normals come from the height gradient by central differences (one-sided at the border):
``n = normalise(-dH/dx, -dH/dy, 1)``. Vertex frames follow the project's rule
(:func:`prt_torch.rig.vertex_frames.vertex_frames`, rows ``(t, b, n)``) with a single rigid part whose
axis is world ``+x`` carried by an identity bone, so ``t`` = ``+x`` projected into the tangent plane and
``b = n x t``.

Generators (all float64 numpy, vectorised over the grid; ``__call__(time) -> (N, N)``):

* :class:`Waves`: a sum of travelling sinusoids with sharpened crests (Gerstner-like peaks),
  ``H = sum_k a_k (2 ((1 + sin(k_k . x - w_k t + p_k)) / 2)^s - 1)``, deep-water dispersion
  ``w_k = sqrt(g |k_k|)``.
* :class:`Terrain`: a fixed rolling base (a few random sinusoids) plus Gaussian bumps that travel on
  circles and breathe (height ``a_j (1 + 0.5 sin(...))``): a deforming terrain.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from prt_torch.errors import check

#: smallest grid (the max pyramid and central differences need a few texels)
MIN_GRID = 4
#: largest grid accepted (memory: the horizon search holds a few ``(N, N)`` float32 maps per level)
MAX_GRID = 2048
#: generator kinds of :func:`make_generator`
KINDS = ("waves", "terrain")


def check_grid_size(n: int) -> int:
    """``n`` as int if ``MIN_GRID <= n <= MAX_GRID``, else a one-line :class:`PrtError`."""
    check(isinstance(n, int | np.integer) and not isinstance(n, bool),
          f"height-field grid size must be an integer, got {n!r}")
    check(MIN_GRID <= int(n) <= MAX_GRID,
          f"height-field grid size must be in [{MIN_GRID}, {MAX_GRID}], got {n}")
    return int(n)


def check_heights(heights: np.ndarray) -> np.ndarray:
    """``heights`` as a float array ``(N, N)`` (square, ``N >= MIN_GRID``, finite) or a one-line :class:`PrtError`.

    Accepts numpy arrays and torch tensors (returned unchanged apart from the checks)."""
    shape = tuple(getattr(heights, "shape", ()))
    check(len(shape) == 2 and shape[0] == shape[1],
          f"heights must be a square (N, N) grid, got shape {shape}")
    check(shape[0] >= MIN_GRID, f"height-field grid too small: {shape[0]} x {shape[1]} (need at least "
          f"{MIN_GRID} x {MIN_GRID})")
    check(shape[0] <= MAX_GRID, f"height-field grid too large: {shape[0]} (at most {MAX_GRID})")
    if isinstance(heights, np.ndarray):
        check(np.issubdtype(heights.dtype, np.floating), f"heights must be floating point, got {heights.dtype}")
        check(bool(np.isfinite(heights).all()), "heights contain NaN or Inf")
    else:
        import torch

        check(isinstance(heights, torch.Tensor) and heights.is_floating_point(),
              f"heights must be a float numpy array or torch tensor, got {type(heights).__name__}")
        check(bool(torch.isfinite(heights).all()), "heights contain NaN or Inf")
    return heights


def check_extent(extent: float) -> float:
    check(np.isfinite(extent) and extent > 0, f"height-field extent must be a positive number, got {extent!r}")
    return float(extent)


def spacing(n: int, extent: float) -> float:
    """Grid spacing ``dx = extent / (n - 1)`` (world units per texel)."""
    return check_extent(extent) / (check_grid_size(n) - 1)


def grid_faces(n: int) -> np.ndarray:
    """``(2 (n-1)^2, 3)`` int64 triangles of the ``n x n`` grid, counter-clockwise seen from ``+z``."""
    n = check_grid_size(n)
    iy, ix = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    v00 = (iy * n + ix).reshape(-1)
    v10, v01, v11 = v00 + 1, v00 + n, v00 + n + 1  # +x, +y, +x+y
    lower = np.stack([v00, v10, v11], axis=1)
    upper = np.stack([v00, v11, v01], axis=1)
    return np.concatenate([lower, upper]).astype(np.int64)


def grid_positions(heights: np.ndarray, extent: float = 1.0) -> np.ndarray:
    """``(N*N, 3)`` float32 world positions ``(ix dx, iy dx, H[iy, ix])`` of the vertices."""
    h = np.asarray(check_heights(heights), dtype=np.float64)
    n = h.shape[0]
    dx = spacing(n, extent)
    iy, ix = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return np.stack([ix * dx, iy * dx, h], axis=-1).reshape(-1, 3).astype(np.float32)


def gradient(heights: np.ndarray, extent: float = 1.0) -> np.ndarray:
    """``(N, N, 2)`` float64 ``(dH/dx, dH/dy)`` by central differences (one-sided at the border)."""
    h = np.asarray(check_heights(heights), dtype=np.float64)
    dx = spacing(h.shape[0], extent)
    gy, gx = np.gradient(h, dx)
    return np.stack([gx, gy], axis=-1)


def grid_normals(heights: np.ndarray, extent: float = 1.0) -> np.ndarray:
    """``(N*N, 3)`` float64 unit normals ``normalise(-dH/dx, -dH/dy, 1)`` of the vertices."""
    g = gradient(heights, extent).reshape(-1, 2)
    nrm = np.concatenate([-g, np.ones((g.shape[0], 1))], axis=1)
    return nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def grid_frames(heights: np.ndarray, extent: float = 1.0) -> np.ndarray:
    """``(N*N, 3, 3)`` float32 vertex frames, rows ``(t, b, n)``, by the project's rule
    (:func:`prt_torch.rig.vertex_frames.vertex_frames`: one part, axis ``+x``, identity bone)."""
    from prt_torch.rig.vertex_frames import vertex_frames

    nrm = grid_normals(heights, extent)
    v = nrm.shape[0]
    one_part = np.zeros(v, np.int64)
    return vertex_frames(nrm, np.eye(3)[None], one_part, np.array([[1.0, 0.0, 0.0]]), np.zeros(1, np.int64))


@dataclass(frozen=True)
class HeightFieldFrame:
    """One animation frame of a height-field receiver.

    Attributes:
        heights: ``(N, N)`` float64.
        positions: ``(V, 3)`` float32 world positions, ``V = N*N``.
        frames: ``(V, 3, 3)`` float32 vertex frames (rows t, b, n).
        faces: ``(T, 3)`` int64.
        extent: side of the square in world units.
    """

    heights: np.ndarray
    positions: np.ndarray
    frames: np.ndarray
    faces: np.ndarray
    extent: float

    @property
    def n(self) -> int:
        return int(self.heights.shape[0])

    @property
    def spacing(self) -> float:
        return spacing(self.n, self.extent)


def make_frame(heights: np.ndarray, extent: float = 1.0, faces: np.ndarray | None = None) -> HeightFieldFrame:
    """Mesh, positions and vertex frames of ``heights (N, N)``."""
    h = np.asarray(check_heights(heights), dtype=np.float64)
    return HeightFieldFrame(h, grid_positions(h, extent), grid_frames(h, extent),
                            grid_faces(h.shape[0]) if faces is None else faces, check_extent(extent))


def _grid(n: int, extent: float) -> tuple[np.ndarray, np.ndarray]:
    c = np.linspace(0.0, check_extent(extent), check_grid_size(n))
    y, x = np.meshgrid(c, c, indexing="ij")
    return x, y


@dataclass
class Waves:
    """Procedural ocean-like waves: a sum of travelling sharpened sinusoids (see the module docstring).

    Args:
        n: grid size ``N``. extent: side of the square (world units).
        n_waves: number of sinusoids. amplitude: total peak height (split over the waves, ``a_k ~ lambda_k``).
        wavelength: ``(min, max)`` wavelengths (world units). sharpness: crest exponent ``s >= 1``.
        direction: mean travel direction (radians) and ``spread`` of the directions (radians).
        seed: random phases and directions.
    """

    n: int
    extent: float = 1.0
    n_waves: int = 8
    amplitude: float = 0.06
    wavelength: tuple[float, float] = (0.08, 0.4)
    sharpness: float = 2.5
    direction: float = 0.6
    spread: float = 1.2
    gravity: float = 9.81
    seed: int = 0
    _k: np.ndarray = field(init=False, repr=False)
    _w: np.ndarray = field(init=False, repr=False)
    _a: np.ndarray = field(init=False, repr=False)
    _p: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_grid_size(self.n)
        check(self.n_waves >= 1, f"waves: n_waves must be >= 1, got {self.n_waves}")
        check(self.sharpness >= 1, f"waves: sharpness must be >= 1, got {self.sharpness}")
        rng = np.random.default_rng(self.seed)
        lam = np.exp(rng.uniform(np.log(self.wavelength[0]), np.log(self.wavelength[1]), self.n_waves))
        ang = self.direction + rng.uniform(-0.5, 0.5, self.n_waves) * self.spread
        kk = 2 * np.pi / lam
        self._k = kk[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        self._w = np.sqrt(self.gravity * kk) * 0.25  # slowed down: a few crests per second on a 1 m tile
        self._a = self.amplitude * lam / lam.sum()
        self._p = rng.uniform(0, 2 * np.pi, self.n_waves)

    def __call__(self, time: float) -> np.ndarray:
        """``(N, N)`` float64 heights at ``time`` seconds."""
        x, y = _grid(self.n, self.extent)
        h = np.zeros_like(x)
        for k, w, a, p in zip(self._k, self._w, self._a, self._p, strict=True):  # a handful of waves
            s = np.sin(k[0] * x + k[1] * y - w * time + p)
            h += a * (2.0 * ((1.0 + s) * 0.5) ** self.sharpness - 1.0)
        return h


@dataclass
class Terrain:
    """A deforming terrain: rolling base plus travelling, breathing Gaussian bumps (see the module docstring).

    Args:
        n: grid size. extent: side (world units). n_bumps: moving bumps. height: bump height.
        width: bump standard deviation (world units). base: amplitude of the rolling base. seed: layout.
    """

    n: int
    extent: float = 1.0
    n_bumps: int = 6
    height: float = 0.12
    width: float = 0.06
    base: float = 0.02
    seed: int = 0
    _c: np.ndarray = field(init=False, repr=False)
    _r: np.ndarray = field(init=False, repr=False)
    _speed: np.ndarray = field(init=False, repr=False)
    _phase: np.ndarray = field(init=False, repr=False)
    _base_k: np.ndarray = field(init=False, repr=False)
    _base_p: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        check_grid_size(self.n)
        check(self.n_bumps >= 0, f"terrain: n_bumps must be >= 0, got {self.n_bumps}")
        rng = np.random.default_rng(self.seed)
        e = self.extent
        self._c = rng.uniform(0.3 * e, 0.7 * e, (self.n_bumps, 2))
        self._r = rng.uniform(0.1 * e, 0.25 * e, self.n_bumps)
        self._speed = rng.uniform(0.3, 0.8, self.n_bumps) * rng.choice([-1.0, 1.0], self.n_bumps)
        self._phase = rng.uniform(0, 2 * np.pi, self.n_bumps)
        self._base_k = rng.normal(0, 2 * np.pi * 3 / e, (4, 2))
        self._base_p = rng.uniform(0, 2 * np.pi, 4)

    def __call__(self, time: float) -> np.ndarray:
        """``(N, N)`` float64 heights at ``time`` seconds."""
        x, y = _grid(self.n, self.extent)
        h = np.zeros_like(x)
        for k, p in zip(self._base_k, self._base_p, strict=True):
            h += self.base * 0.5 * np.sin(k[0] * x + k[1] * y + p)
        ang = self._phase + self._speed * time
        cx = self._c[:, 0] + self._r * np.cos(ang)
        cy = self._c[:, 1] + self._r * np.sin(ang)
        amp = self.height * (1.0 + 0.5 * np.sin(1.7 * time + self._phase))
        inv = -0.5 / self.width ** 2
        for j in range(self.n_bumps):  # a handful of bumps, each a whole-grid array op
            h += amp[j] * np.exp(inv * ((x - cx[j]) ** 2 + (y - cy[j]) ** 2))
        return h


def make_generator(kind: str, n: int, extent: float = 1.0, seed: int = 0) -> Waves | Terrain:
    """A height-field generator by name (:data:`KINDS`)."""
    check(kind in KINDS, f"unknown height-field kind {kind!r}: expected one of {list(KINDS)}")
    return Waves(n, extent, seed=seed) if kind == "waves" else Terrain(n, extent, seed=seed)
