"""Horizon angles of a height field in ``n`` azimuthal wedges from a multi-resolution MAX pyramid (after [SN08]).

For a vertex ``p`` and the wedge ``i`` centred on the world azimuth ``phi_i = 2 pi i / n`` (measured from
``+x`` toward ``+y``; the wedge spans ``phi_i +- pi / n``) the horizon elevation is

    h_i(p) = max_{d > 0} atan((H(p + d u_i) - H(p)) / (d dx)),     u_i = (cos phi_i, sin phi_i) in texels,

the highest terrain seen along the wedge's centre direction ([SN08] eq. 4 takes one horizon per wedge).
An exhaustive search costs ``O(N)`` texels per direction. Here it costs ``O(log N)`` levels:

* **Pyramid.** Level ``L`` holds ``M_L = max`` of the heights over the ``3^L x 3^L`` window centred on each
  texel (same resolution as the grid, so every level is centred on every texel; built by one dilated
  ``3 x 3`` ``max_pool2d`` per level, ``M_{L+1} = maxpool_3x3, dilation 3^L (M_L)``, on a ``-inf``-padded canvas).
* **Search.** Along ``u_i`` the distances ``d`` are visited level by level: level 0 at ``d = 1, 2, ...,
  3 rho - 1`` (every texel, exact heights), level ``L >= 1`` at ``d = rho 3^L + k 3^L`` for
  ``k = 0 .. 2 rho - 1`` (one sample per window width, so consecutive windows tile the ray without gaps);
  ``rho`` (:data:`REACH`, default 6) sets the accuracy: ``2 rho`` samples per level. Each sample reads
  ``M_L`` bilinearly at ``p + d u_i`` and takes ``atan((M_L - H(p)) / (d dx))``. Samples that leave the grid
  are skipped (nothing occludes beyond the edge); a direction with no sample has horizon ``-pi/2``.
  Total ``3 rho - 1 + 2 rho L_max`` samples, ``L_max ~ log_3(sqrt 2 N / rho)``: 56 at ``N = 512``, ``rho = 6``
  (vs ~700 texels for the exhaustive scan).

**Approximation** (documented, tested against the exhaustive scan): a level-``L`` sample stands for the
window of half-width ``r_L = (3^L - 1) / 2 <= d / (2 rho)`` around it, i.e. the highest point of the
window is placed at the window's centre distance. It is *conservative in height* (the window max is at
least the terrain there; on a slope the window's uphill corner is up to ``|grad H| r_L`` higher, so even a
tilted plane gets slightly raised distant horizons) and at most ``1 / (2 rho)`` (8 %) off in distance, so
distant horizons are within ``~ atan(tan h (1 +- 1/(2 rho)))`` of the exhaustive value, up to the bilinear
reconstruction of the max map; nearby terrain (``d < 3 rho`` texels) is sampled exactly at every texel step.
``rho = 6`` is the default because the window bias dominates the visibility error at ``rho = 3`` on smooth
bumps (relative SH error vs Embree 0.030 at ``rho = 3``, 0.014 at ``rho = 6``, 0.011 with exhaustive
horizons; 64^2 terrain, 16 wedges).

**Sub-sampling** (the paper's "we sub-sample the visibility and shade with RPOs at full resolution"):
with ``stride s > 1`` the search runs only at every ``s``-th vertex of each axis (plus the last one) on the
full-resolution pyramid, and the horizon angles are bilinearly interpolated to every vertex.

Everything is torch, vectorised over vertices: the only Python loops are over wedges, pyramid levels and
the ``O(log N)`` samples of the schedule, each sample one whole-grid tensor operation on strided views.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from prt_torch.errors import check
from prt_torch.heightfield.surface import check_extent, check_heights

#: default ``rho``: a level-``L`` window is used from ``rho 3^L`` texels away (``2 rho`` samples per level)
REACH = 6


def check_wedges(n_wedges: int) -> int:
    """``n_wedges`` as int if it is an integer >= 1, else a one-line :class:`~prt_torch.errors.PrtError`."""
    check(isinstance(n_wedges, int | np.integer) and not isinstance(n_wedges, bool) and n_wedges >= 1,
          f"number of wedges must be an integer >= 1, got {n_wedges!r}")
    return int(n_wedges)


def wedge_azimuths(n_wedges: int) -> np.ndarray:
    """``(n,)`` float64 wedge centres ``phi_i = 2 pi i / n`` (radians, from ``+x`` toward ``+y``)."""
    return 2.0 * np.pi * np.arange(check_wedges(n_wedges)) / n_wedges


@dataclass(frozen=True)
class SearchSchedule:
    """The distances (texels) and pyramid levels of the horizon search of an ``N x N`` grid.

    Attributes:
        distance: ``(S,)`` float64 sample distances in texels, increasing.
        level: ``(S,)`` int64 pyramid level of each sample.
        n_levels: number of pyramid levels built (``level.max() + 1``).
    """

    distance: np.ndarray
    level: np.ndarray
    n_levels: int

    @classmethod
    def make(cls, n: int, reach: int = REACH) -> SearchSchedule:
        check(isinstance(reach, int | np.integer) and reach >= 1, f"horizon reach must be an integer >= 1, got {reach}")
        far = math.sqrt(2.0) * (n - 1)
        dist = [float(d) for d in range(1, 3 * reach)]
        lev = [0] * len(dist)
        level = 1
        while 3 * reach * 3 ** (level - 1) <= far:  # level L starts at rho 3^L
            w = 3 ** level
            for k in range(2 * reach):
                dist.append(float(reach * w + k * w))
                lev.append(level)
            level += 1
        d = np.asarray(dist)
        keep = d <= far + 1e-9
        d, lv = d[keep], np.asarray(lev, dtype=np.int64)[keep]
        return cls(d, lv, int(lv.max()) + 1)

    @property
    def n_samples(self) -> int:
        return int(self.distance.shape[0])


def max_pyramid(heights: torch.Tensor, n_levels: int) -> torch.Tensor:
    """``(n_levels, N, N)``: level ``L`` = max of ``heights (N, N)`` over the centred ``3^L x 3^L`` window
    (clipped at the border).

    The levels are built on a canvas padded with ``-inf`` by the largest radius, so a window centred off the
    grid still carries the max of its part inside the grid to the next level (exact, not only inside)."""
    pad = (3 ** (n_levels - 1) - 1) // 2
    x = F.pad(heights[None, None], (pad, pad, pad, pad), value=-math.inf)
    levels = [heights]
    for level in range(1, n_levels):
        d = 3 ** (level - 1)
        x = F.max_pool2d(F.pad(x, (d, d, d, d), value=-math.inf), kernel_size=3, stride=1, dilation=d)
        levels.append(x[0, 0, pad: x.shape[2] - pad, pad: x.shape[3] - pad])
    return torch.stack(levels)


def _split(offset: float) -> tuple[int, int, float]:
    """Bilinear taps of a constant sample offset (texels): ``(k0, k1, frac)`` with ``k1 = k0`` when the offset
    is (numerically) an integer, so axis-aligned samples need no neighbour row/column."""
    k0 = math.floor(offset)
    f = offset - k0
    if f < 1e-9:
        return k0, k0, 0.0
    if f > 1.0 - 1e-9:
        return k0 + 1, k0 + 1, 0.0
    return k0, k0 + 1, f


def _valid(n: int, o: int, s: int, c: int, k0: int, k1: int) -> tuple[int, int]:
    """Range ``[j0, j1)`` of ``j < c`` whose taps ``o + s j + k0`` and ``o + s j + k1`` lie in ``[0, n - 1]``."""
    j0 = max(0, -((o + k0) // s))
    j1 = min(c, (n - 1 - o - k1) // s + 1) if n - 1 - o - k1 >= 0 else 0
    return j0, max(j0, j1)


Lattice = tuple[int, int, int]  # (offset, step, count) of searched indices along one axis


def _search(pyr: torch.Tensor, h: torch.Tensor, dx: float, sched: SearchSchedule, phi: float, ry: Lattice,
            rx: Lattice) -> torch.Tensor:
    """``(cy, cx)`` max horizon tangent along azimuth ``phi`` at the vertices ``(oy + sy j, ox + sx k)``
    (``-inf`` where no sample lies inside the grid). Whole-lattice tensor ops per sample, no gathers."""
    n = h.shape[0]
    (oy, sy, cy), (ox, sx, cx) = ry, rx
    hc = h[oy: oy + sy * (cy - 1) + 1: sy, ox: ox + sx * (cx - 1) + 1: sx]
    best = torch.full((cy, cx), -math.inf, dtype=h.dtype)
    for d, level in zip(sched.distance, sched.level, strict=True):  # O(log N) samples
        x0, x1, fx = _split(d * math.cos(phi))
        y0, y1, fy = _split(d * math.sin(phi))
        jx0, jx1 = _valid(n, ox, sx, cx, x0, x1)
        jy0, jy1 = _valid(n, oy, sy, cy, y0, y1)
        if jx1 <= jx0 or jy1 <= jy0:
            continue  # the whole sample lies outside the grid
        m = pyr[level]

        def tap(ky: int, kx: int, m: torch.Tensor = m, jy0: int = jy0, jy1: int = jy1, jx0: int = jx0,
                jx1: int = jx1) -> torch.Tensor:
            r0, c0 = oy + sy * jy0 + ky, ox + sx * jx0 + kx
            return m[r0: r0 + sy * (jy1 - jy0 - 1) + 1: sy, c0: c0 + sx * (jx1 - jx0 - 1) + 1: sx]

        val = tap(y0, x0)
        if fx:
            val = torch.lerp(val, tap(y0, x1), fx)
        if fy:
            bot = tap(y1, x0)
            if fx:
                bot = torch.lerp(bot, tap(y1, x1), fx)
            val = torch.lerp(val, bot, fy)
        tan = (val - hc[jy0:jy1, jx0:jx1]).mul_(1.0 / (d * dx))
        torch.maximum(best[jy0:jy1, jx0:jx1], tan, out=best[jy0:jy1, jx0:jx1])
    return best


def _search_points(pyr: torch.Tensor, h: torch.Tensor, dx: float, sched: SearchSchedule, phi: float,
                   py: torch.Tensor, px: torch.Tensor) -> torch.Tensor:
    """``(K,)`` max horizon tangent along ``phi`` at the vertices ``(py, px)`` (integer tensors ``(K,)``), all
    samples at once by gathers (for the few vertices off the strided lattice: the last row and column)."""
    n = h.shape[0]
    dist = torch.as_tensor(sched.distance, dtype=torch.float64)[:, None]
    sx = px[None].double() + dist * math.cos(phi)  # (S, K)
    sy = py[None].double() + dist * math.sin(phi)
    valid = (sx >= -1e-9) & (sx <= n - 1 + 1e-9) & (sy >= -1e-9) & (sy <= n - 1 + 1e-9)
    x0 = sx.floor().clamp(0, n - 2)
    y0 = sy.floor().clamp(0, n - 2)
    fx = (sx - x0).clamp(0, 1).to(h.dtype)
    fy = (sy - y0).clamp(0, 1).to(h.dtype)
    flat = pyr.reshape(-1)
    base = torch.as_tensor(sched.level)[:, None] * (n * n) + y0.long() * n + x0.long()
    top = torch.lerp(flat[base], flat[base + 1], fx)
    bot = torch.lerp(flat[base + n], flat[base + n + 1], fx)
    tan = (torch.lerp(top, bot, fy) - h[py, px][None]) / (dist * dx).to(h.dtype)
    return torch.where(valid, tan, torch.full_like(tan, -math.inf)).amax(dim=0)


def horizon_angles(
    heights: torch.Tensor | np.ndarray,
    n_wedges: int,
    extent: float = 1.0,
    stride: int = 1,
    reach: int = REACH,
) -> torch.Tensor:
    """Horizon elevation angles (radians) of every vertex in every wedge (see the module docstring).

    Args:
        heights: ``(N, N)`` heights (world units; numpy or torch; float32 unless a float64 tensor is given).
        n_wedges: number of azimuthal wedges ``n >= 1``.
        extent: side of the square (world units); the grid spacing is ``extent / (N - 1)``.
        stride: search the vertices ``(s i, s j)`` plus the last row and column only, and interpolate the rest
            bilinearly (1: every vertex).
        reach: ``rho`` of the schedule (:data:`REACH`).

    Returns:
        ``(N, N, n)`` angles in ``[-pi/2, pi/2)``; ``-pi/2`` where nothing lies along the direction.
    """
    check_heights(heights)
    n_wedges = check_wedges(n_wedges)
    check(isinstance(stride, int | np.integer) and not isinstance(stride, bool) and stride >= 1,
          f"horizon stride must be an integer >= 1, got {stride}")
    h = torch.as_tensor(heights)
    if h.dtype != torch.float64:
        h = h.float()
    n = h.shape[0]
    s = int(stride)
    dx = check_extent(extent) / (n - 1)
    sched = SearchSchedule.make(n, reach)
    pyr = max_pyramid(h, sched.n_levels)  # (L, N, N)
    nc = (n - 1) // s + 1
    main: Lattice = (0, s, nc)
    last = (n - 1) % s != 0  # the last row/column is off the lattice: search it too (gathers, few vertices)
    if last:
        idx = torch.cat([torch.arange(0, n, s), torch.tensor([n - 1])])  # (nc + 1,)
        edge = torch.full((nc + 1,), n - 1)
        py = torch.cat([idx[:-1], edge])  # last column (rows idx[:-1]), then last row (all columns)
        px = torch.cat([edge[:-1], idx])
    out = []
    for phi in wedge_azimuths(n_wedges):
        grid = _search(pyr, h, dx, sched, phi, main, main)
        if last:
            strip = _search_points(pyr, h, dx, sched, phi, py, px)
            grid = torch.cat([grid, strip[:nc, None]], dim=1)  # (nc, nc + 1)
            grid = torch.cat([grid, strip[None, nc:]], dim=0)  # (nc + 1, nc + 1)
        out.append(grid)
    ang = torch.atan(torch.stack(out, dim=-1))  # (Nc, Nc, n); atan(-inf) = -pi/2
    if s == 1:
        return ang
    # bilinear interpolation from the searched positions to every vertex
    coarse = np.arange(0, n, s) if not last else np.append(np.arange(0, n, s), n - 1)
    fine = np.arange(n, dtype=np.float64)
    hi = np.clip(np.searchsorted(coarse, fine, side="right"), 1, len(coarse) - 1)
    lo = hi - 1
    w = torch.as_tensor((fine - coarse[lo]) / (coarse[hi] - coarse[lo]), dtype=ang.dtype)
    lo_t, hi_t = torch.as_tensor(lo), torch.as_tensor(hi)
    rows = torch.lerp(ang[lo_t], ang[hi_t], w[:, None, None])  # (N, Nc, n)
    return torch.lerp(rows[:, lo_t], rows[:, hi_t], w[None, :, None])
