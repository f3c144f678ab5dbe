"""SHEXP of sphere blockers in one compiled pass per frame (numba + numpy, no torch, no onnxruntime).

The same numbers as :class:`prt_torch.shexp.ShexpVisibility` (its ``below_horizon=None`` form, the run's
``shexp.onnx``; parity tested to :data:`prt_torch.shexp.graph.SHEXP_PARITY_RTOL`), for the scene player:

* **log sum** (:func:`log_sums`): per receiver ``p`` and sphere ``(c, r)``, the offset in the receiver's frame
  (``x = t . c - t . p``, three fused multiply-adds per row), ``cos(alpha) = sqrt(d^2 - r^2) / d``, the nearest row of
  the run-time log table (the zero row where the sphere contains the receiver) and the rotated ZH summed into
  the receiver's ``C`` coefficients (:mod:`prt_torch.shexp.zonal_sum`'s factorisation, generated per order with
  its constants inlined). Receivers come in blocks of :data:`BLOCK` consecutive ones; the loop over a block's
  receivers is the inner one (SIMD over receivers, one sphere at a time), blocks run on numba's threads. Each block
  reads only its own list of spheres (:func:`block_spheres`, the culling below).
* **exponential** (:func:`hyb_exp`): HYB exactly as :class:`prt_torch.shexp.exponential.SHExponential` (DC apart,
  ``k`` halvings, OL, ``k`` squarings through point values), as float32 matmuls over the receivers still squaring.

**Culling, with its bound** (:func:`block_spheres`). A sphere of radius ``r`` seen from distance ``d > r`` is a
cap of solid angle ``Omega = 2 pi (1 - sqrt(1 - (r / d)^2))``; its log-SH is the tabulated ZH ``g(alpha)``
rotated, whose L2 norm is at most ``B Omega`` with ``B = log_norm_bound(tables, eps)`` (the largest ratio over the
rows such a cap can read at its nearest row; 2.26 at order 4 for small caps). Per block of receivers (centre
``m``, radius ``rho``) a sphere's cap is at most ``Omega_max`` with ``d >= |c - m| - rho``; the spheres of smallest
``Omega_max`` are dropped while their sum stays ``<= eps`` (``eps``: :data:`CULL_SOLID_ANGLE` by default,
``4 pi x 1e-4``: one ten-thousandth of the sphere of directions, the scale of the ONNX path's receiver culling).
So at every receiver the culled log differs from the full one by at most ``B eps`` (L2, triangle inequality), and
its visibility by about that much (``exp*(f + e) ~ exp*(f) (x) (1 + e)`` with ``|V| <= 1``; the test asserts
``||V_culled - V||_2 <= B eps`` at every vertex of a crowd, measured ~0.45 ``B eps`` at ``eps`` = 10x the default
and 0 at the default, where the dropped caps are below the table's first row and read zero anyway; a receiver
whose HYB step count the culling changes jumps by HYB's own step, as the graph's does when a pose moves it across
the threshold). A block with no sphere left gets the constant 1 without the exponential: a floor far from every
character costs one distance test per
(block, sphere). ``eps = 0`` keeps every sphere (the unculled reference).
"""

from __future__ import annotations

import base64
import functools
import json
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.sh.basis import check_order, norm_consts
from prt_torch.shapes import check_shape

#: receivers per block (the unit of culling and of the SIMD loop)
BLOCK = 64
#: default culling budget: total solid angle (sr) of the spheres a receiver may ignore (module doc)
CULL_SOLID_ANGLE = 4.0 * math.pi * 1e-4


#: the HYB exponential's constants (the source of :mod:`prt_torch.shexp.exponential`'s and the graph's)
OL_MAX = 64.0
"""Largest tabulated magnitude ``||f^||`` of the OL table (clamped beyond)."""
HYB_THRESHOLD = 0.125
"""HYB scales ``f^`` below this magnitude before OL. The OL error, amplified by each squaring, dominates HYB's
error against the brute-force exponential: 0.5 -> 10-20 %, 0.125 -> 3-5 % on three strongly overlapping
spheres (order 4)."""
MAX_SQUARINGS = 10
"""Upper bound on HYB's squaring steps (magnitudes up to ``HYB_THRESHOLD * 2**10 = 128``; the built-in
character needs at most 7 with 32-64 spheres)."""


@functools.cache
def monic_legendre(order: int) -> tuple[tuple[tuple[float, ...], ...], np.ndarray]:
    """``(qhat, scale)``: ``qhat[i]`` the monic polynomial coefficients (lowest power first) of ``Q_lm`` for the
    ``(l, m >= 0)`` pairs in :func:`lobe_pairs` order; ``scale (C,)`` float64 ``K_lm * lead_lm`` per SH index."""
    check_order(order, 16)
    k = norm_consts(order)
    qhat: list[tuple[float, ...]] = []
    scale = np.zeros(order * order)
    for l, m in lobe_pairs(order):
        q = legendre_q(l, m)
        lead = q[-1]
        qhat.append(tuple(float(c) for c in q / lead))
        scale[l * (l + 1) + m] = k[l][m] * lead
        scale[l * (l + 1) - m] = k[l][m] * lead
    return tuple(qhat), scale


def lobe_pairs(order: int) -> list[tuple[int, int]]:
    """The ``(l, m >= 0)`` pairs in the order of :func:`monic_legendre` (m outer, l inner)."""
    return [(l, m) for m in range(order) for l in range(m, order)]


@functools.cache
def legendre_q(l: int, m: int) -> np.ndarray:
    """Coefficients (lowest power first, float64) of ``Q_lm(z)``: ``P_l^m = sin^m Q_lm``, no Condon-Shortley
    phase; the recurrence of :func:`prt_torch.sh.basis.sh_basis`."""
    poly = np.polynomial.Polynomial
    zed = poly([0.0, 1.0])
    qmm = poly([float(math.prod(range(1, 2 * m, 2))) if m > 0 else 1.0])
    if l == m:
        return qmm.coef
    prev2, prev = qmm, zed * (2 * m + 1) * qmm
    for ll in range(m + 2, l + 1):
        prev2, prev = prev, ((2 * ll - 1) * zed * prev - (ll + m - 1) * prev2) / (ll - m)
    return prev.coef


#: the ``shexp.onnx`` metadata property holding :class:`ShexpTables` (:meth:`ShexpTables.to_metadata`)
TABLES_METADATA_KEY = "prt.shexp_tables"


@dataclass(frozen=True)
class ShexpTables:
    """The constants of the SHEXP graph at one order: ``table (N + 1, n)`` the run-time log table
    (``prt_torch.shexp.tables.cos_log_table``), ``ol (N_OL, 2)`` the OL coefficients, ``to_points (C, Q)`` and
    ``from_points (Q, C)`` the squaring operators (``prt_torch.shexp.exponential.square_operators``); float32."""

    order: int
    table: np.ndarray
    ol: np.ndarray
    to_points: np.ndarray
    from_points: np.ndarray

    def to_metadata(self) -> dict[str, str]:
        """The tables as one ONNX metadata property (:data:`TABLES_METADATA_KEY`: JSON of ``{name: [shape, base64
        of the little-endian float32 bytes]}``), which the SHEXP export writes next to the same constants."""
        enc = {n: [list(a.shape), base64.b64encode(np.ascontiguousarray(a, dtype="<f4").tobytes()).decode("ascii")]
               for n, a in (("table", self.table), ("ol", self.ol), ("to_points", self.to_points),
                            ("from_points", self.from_points))}
        return {TABLES_METADATA_KEY: json.dumps({"order": self.order, **enc})}

    @staticmethod
    def from_graph(path: str | os.PathLike[str]) -> ShexpTables:
        """The tables of an exported HYB ``shexp.onnx`` (torch- and onnx-free: its metadata read through onnxruntime;
        :meth:`to_metadata`); a graph without them (an older export) is a one-line error naming ``prt export``."""
        import onnxruntime as ort

        try:
            props = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta() \
                .custom_metadata_map
        except Exception as exc:  # onnxruntime raises its own Fail / InvalidProtobuf
            raise PrtError(f"{path}: not a readable ONNX graph ({type(exc).__name__}): re-export the run "
                           "(`prt export RUN --force`)") from None
        text = props.get(TABLES_METADATA_KEY)
        if not (props.get("kind") == "shexp" and props.get("method") == "hyb" and text):
            raise PrtError(f"{path}: not a HYB shexp graph with its tables ({TABLES_METADATA_KEY}): re-export the "
                           "run (`prt export RUN --force`)")
        try:
            d = json.loads(text)
            arr = {n: np.frombuffer(base64.b64decode(d[n][1]), dtype="<f4").reshape(d[n][0]).astype(np.float32)
                   for n in ("table", "ol", "to_points", "from_points")}
            order = int(d["order"])
        except (ValueError, KeyError, TypeError, IndexError):
            raise PrtError(f"{path}: its {TABLES_METADATA_KEY} metadata is damaged: re-export the run "
                           "(`prt export RUN --force`)") from None
        c = order * order
        check(arr["table"].ndim == 2 and arr["table"].shape[1] == order and arr["ol"].shape[1:] == (2,)
              and arr["to_points"].shape[0] == c and arr["from_points"].shape == arr["to_points"].shape[::-1],
              f"{path}: its {TABLES_METADATA_KEY} metadata does not have the SHEXP tables' shapes")
        return ShexpTables(order, arr["table"], arr["ol"], arr["to_points"], arr["from_points"])


def log_norm_bound(tables: ShexpTables, eps: float = CULL_SOLID_ANGLE) -> float:
    """``B``: a sphere of cap ``Omega <= eps`` adds at most ``B Omega`` (L2) to a receiver's log (module doc). The
    largest ``||zh_to_sh(g_i)||_2 / Omega_lo(i)`` over the rows ``i`` such a cap can read, ``Omega_lo(i) = 2 pi (1 -
    (i + 1/2) / (N - 1))`` the smallest cap read at row ``i`` (the nearest row of ``cos(alpha)``; the last row,
    ``alpha = 0``, is zero)."""
    t = np.asarray(tables.table[:-1], dtype=np.float64)  # the zero row (inside the sphere) apart
    n_rows, n = t.shape
    norm = np.sqrt((t * t * (2 * np.arange(n) + 1)[None] / (4.0 * math.pi)).sum(1))  # |f_l.|^2 = g_l^2 (2l+1)/4pi
    lo = 2.0 * math.pi * (1.0 - np.minimum((np.arange(n_rows) + 0.5) / (n_rows - 1), 1.0))
    ok = (lo > 0) & (lo <= max(float(eps), lo[lo > 0].min()))
    return float((norm[ok] / lo[ok]).max())


#: the generated SHEXP kernel (:func:`_kernel_source`): ``@ORDER@``, ``@C@``, ``@BLOCK@``, ``@SQ@`` and ``@INNER@`` (the
#: per-pair zonal sum) filled in per order
_KERNEL_TEMPLATE = '''"""Generated by prt_torch.scene.shexp_kernel (SHEXP log sum + HYB, order @ORDER@); do not edit."""
import numba
import numpy as np


@numba.njit(cache=True, parallel=True, fastmath=True, nogil=True)
def kernel(rx, starts, spheres, centers, radii, table, scale, ol, to_points, from_points, hyb, max_sq, ol_max, perm,
           out):
    nb = starts.shape[0] - 1
    v = rx.shape[1]
    n = table.shape[0] - 1
    nol = ol.shape[0]
    nq = to_points.shape[1]
    for b in numba.prange(nb):
        lo = b * @BLOCK@
        hi = min(lo + @BLOCK@, v)
        acc = np.zeros((@C@, @BLOCK@), np.float32)
        if starts[b] == starts[b + 1]:  # no sphere left: the constant 1 (= exp*(0): OL's row 0 is (1, 1))
            for j in range(hi - lo):
                out[perm[lo + j], 0] = np.float32(@SQ@)
                for cc in range(1, @C@):
                    out[perm[lo + j], cc] = np.float32(0.0)
            continue
        for k in range(starts[b], starts[b + 1]):
            s = spheres[k]
            cx = centers[s, 0]
            cy = centers[s, 1]
            cz = centers[s, 2]
            r2 = radii[s] * radii[s]
            for j in range(hi - lo):
                q = lo + j
                x = rx[0, q] * cx + rx[1, q] * cy + rx[2, q] * cz - rx[3, q]
                y = rx[4, q] * cx + rx[5, q] * cy + rx[6, q] * cz - rx[7, q]
                z = rx[8, q] * cx + rx[9, q] * cy + rx[10, q] * cz - rx[11, q]
                d2 = x * x + y * y + z * z
                inv = np.float32(1.0) / np.sqrt(max(d2, np.float32(1e-24)))
                ca = np.sqrt(max(d2 - r2, np.float32(0.0))) * inv
                inside = np.float32(1.0) if d2 <= r2 else np.float32(0.0)
                row = np.int32(min(ca * np.float32(n - 1) + np.float32(0.5) + inside * np.float32(n), np.float32(n)))
@INNER@
        nj = hi - lo
        # HYB exp* per receiver (SHExponential's steps): DC apart, k halvings, OL, k masked squarings
        kk = np.zeros(@BLOCK@, np.int32)
        dc = np.empty(@BLOCK@, np.float32)
        kmax = 0
        for j in range(nj):
            for cc in range(@C@):
                acc[cc, j] *= scale[cc]
            dc[j] = acc[0, j]
            m2 = np.float32(0.0)
            for cc in range(1, @C@):
                m2 += acc[cc, j] * acc[cc, j]
            mag = np.sqrt(m2)
            kf = np.ceil(np.log2(max(mag / np.float32(hyb), np.float32(1.0))))
            kf = min(max(kf, np.float32(0.0)), np.float32(max_sq))
            kk[j] = np.int32(kf)
            kmax = max(kmax, kk[j])
            half = np.float32(2.0) ** (-kf)
            xo = min(max(np.sqrt(mag * half / np.float32(ol_max)), np.float32(0.0)), np.float32(1.0))
            xo *= np.float32(nol - 1)
            i0 = min(np.floor(xo), np.float32(nol - 2))
            wo = xo - i0
            ii = np.int32(i0)
            a = ol[ii, 0] * (np.float32(1.0) - wo) + ol[ii + 1, 0] * wo
            bb = (ol[ii, 1] * (np.float32(1.0) - wo) + ol[ii + 1, 1] * wo) * half
            acc[0, j] = a * np.float32(@SQ@)
            for cc in range(1, @C@):
                acc[cc, j] *= bb
        h = np.empty((nq, @BLOCK@), np.float32)
        msk = np.empty(@BLOCK@, np.float32)
        for step in range(kmax):  # a loop over squaring steps: g <- sq(m g) + (1 - m) g, m = [k > step]
            for j in range(nj):
                msk[j] = np.float32(1.0) if kk[j] > step else np.float32(0.0)
            for qq in range(nq):
                for j in range(nj):
                    h[qq, j] = np.float32(0.0)
                for cc in range(@C@):
                    t = to_points[cc, qq]
                    for j in range(nj):
                        h[qq, j] += t * acc[cc, j]
                for j in range(nj):
                    hv = h[qq, j] * msk[j]
                    h[qq, j] = hv * hv
            for cc in range(@C@):
                for j in range(nj):
                    acc[cc, j] *= np.float32(1.0) - msk[j]
                for qq in range(nq):
                    t = from_points[qq, cc]
                    for j in range(nj):
                        acc[cc, j] += t * h[qq, j]
        for j in range(nj):
            e = np.exp(dc[j] / np.float32(@SQ@))
            for cc in range(@C@):
                out[perm[lo + j], cc] = acc[cc, j] * e

'''


def _kernel_source(order: int) -> str:
    """Python source of the SHEXP kernel at ``order`` (module doc): :mod:`prt_torch.shexp.zonal_sum`'s monic
    Legendre factors and recurrences, unrolled, its scale applied before the exponential."""

    qhat, _ = monic_legendre(order)
    body = ["ux = x * inv", "uy = y * inv", "uz = z * inv", "c1 = ux", "s1 = uy"]
    for m in range(2, order):
        body += [f"c{m} = c{m - 1} * ux - s{m - 1} * uy", f"s{m} = s{m - 1} * ux + c{m - 1} * uy"]
    for p in range(2, order):
        body.append(f"z{p} = z{p - 1} * uz" if p > 2 else "z2 = uz * uz")
    body.append("z1 = uz")
    body += [f"g{l} = table[row, {l}]" for l in range(order)]
    for (l, m), q in zip(lobe_pairs(order), qhat, strict=True):
        w = f"g{l}"
        if len(q) > 1:
            terms = [f"z{len(q) - 1}"] + [repr(float(q[j])) if j == 0 else f"{float(q[j])!r} * z{j}"
                                          for j in range(len(q) - 1) if q[j] != 0.0]
            w = f"g{l} * ({' + '.join(terms)})"
        if m == 0:
            body.append(f"acc[{l * (l + 1)}, j] += {w}")
        else:
            body += [f"w = {w}", f"acc[{l * (l + 1) + m}, j] += w * c{m}", f"acc[{l * (l + 1) - m}, j] += w * s{m}"]
    return (_KERNEL_TEMPLATE.replace("@INNER@", "\n".join(" " * 16 + s for s in body))
            .replace("@ORDER@", str(order)).replace("@C@", str(order * order)).replace("@BLOCK@", str(BLOCK))
            .replace("@SQ@", repr(math.sqrt(4 * math.pi))))


def sh_basis_lines(order: int, x: str, y: str, z: str) -> list[str]:
    """Python statements (for generated kernels) setting ``y0 .. y{C-1}`` to the real SH basis
    (:func:`prt_torch.sh.basis.sh_basis`'s) at the unit direction of the expressions ``x, y, z``: the factorisation
    of :mod:`prt_torch.shexp.zonal_sum` with its constants inlined."""

    qhat, scale = monic_legendre(order)
    out = [f"bx = {x}", f"by = {y}", f"bz = {z}", "bc1 = bx", "bs1 = by", "bz1 = bz"]
    for m in range(2, order):
        out += [f"bc{m} = bc{m - 1} * bx - bs{m - 1} * by", f"bs{m} = bs{m - 1} * bx + bc{m - 1} * by"]
    for p in range(2, order):
        out.append(f"bz{p} = bz{p - 1} * bz")
    for (l, m), q in zip(lobe_pairs(order), qhat, strict=True):
        poly = "1.0"
        if len(q) > 1:
            poly = " + ".join([f"bz{len(q) - 1}"] + [repr(float(q[j])) if j == 0 else f"{float(q[j])!r} * bz{j}"
                                                      for j in range(len(q) - 1) if q[j] != 0.0])
        k0 = l * (l + 1)
        if m == 0:
            out.append(f"y{k0} = {float(scale[k0])!r} * ({poly})")
        else:
            out += [f"y{k0 + m} = {float(scale[k0 + m])!r} * ({poly}) * bc{m}",
                    f"y{k0 - m} = {float(scale[k0 - m])!r} * ({poly}) * bs{m}"]
    return out


def generated(name: str, source: str, function: str = "kernel") -> Any:
    """``function`` of generated numba ``source``, compiled once and cached on disk: the source is written to
    ``$PRT_CACHE_DIR`` (default ``~/.cache/prt_torch``) ``/kernels/<name>_<hash>.py`` and imported, so that numba's
    ``cache=True`` keeps its machine code between processes (seconds of compilation otherwise)."""
    import hashlib
    import importlib.util
    import sys
    from pathlib import Path

    digest = hashlib.sha256(source.encode()).hexdigest()[:16]
    mod_name = f"prt_kernel_{name}_{digest}"
    if mod_name in sys.modules:
        return getattr(sys.modules[mod_name], function)
    root = Path(os.environ.get("PRT_CACHE_DIR") or Path.home() / ".cache" / "prt_torch") / "kernels"
    path = root / f"{mod_name}.py"
    try:
        root.mkdir(parents=True, exist_ok=True)
        if not path.is_file() or path.read_text() != source:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(source)
            tmp.replace(path)
    except OSError as e:
        raise PrtError(f"cannot write the compiled kernel {path}: {e} (set PRT_CACHE_DIR to a writable folder)") from e
    spec = importlib.util.spec_from_file_location(mod_name, path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = mod
    spec.loader.exec_module(mod)
    return getattr(mod, function)


@functools.cache
def _kernel(order: int) -> Any:
    """The compiled SHEXP kernel at ``order`` (:func:`generated`)."""

    fn = generated(f"shexp{order}", _kernel_source(order))
    scale = np.ascontiguousarray(monic_legendre(order)[1], dtype=np.float32)
    return fn, scale


def receiver_rows(points: np.ndarray, frames: np.ndarray | None) -> np.ndarray:
    """``(12, V)`` float32 ``[t; -t.p; b; -b.p; n; -n.p]`` rows (``x = t . c - t . p``) of receivers ``points (V, 3)``
    in frames ``(V, 3, 3)`` (rows t, b, n; ``None``: the world frame)."""
    p = np.asarray(points, dtype=np.float32)
    v = p.shape[0]
    f = np.broadcast_to(np.eye(3, dtype=np.float32), (v, 3, 3)) if frames is None else np.asarray(frames, np.float32)
    out = np.empty((12, v), np.float32)
    for a in range(3):  # the three frame rows
        out[4 * a:4 * a + 3] = f[:, a, :].T
        out[4 * a + 3] = np.einsum("vk,vk->v", f[:, a, :], p)
    return out


def shexp_blocks(rows: np.ndarray, starts: np.ndarray, spheres: np.ndarray, centers: np.ndarray,
                 radii: np.ndarray, perm: np.ndarray, tables: ShexpTables) -> np.ndarray:
    """``(V, C)`` float32 visibility (module doc: log sum and HYB in one pass) of receivers ``rows (12, V)``
    (:func:`receiver_rows`, in block order), block ``b`` (receivers ``b BLOCK ..``) under the spheres
    ``spheres[starts[b]:starts[b + 1]]`` of ``centers (S, 3)``, ``radii (S,)``; receiver ``i`` of the rows written
    to output row ``perm[i]``. No checks (the caller's)."""
    fn, scale = _kernel(tables.order)
    out = np.empty((rows.shape[1], tables.order ** 2), np.float32)
    if out.shape[0]:
        fn(rows, starts, spheres, centers, radii, tables.table, scale, tables.ol, tables.to_points,
           tables.from_points, HYB_THRESHOLD, MAX_SQUARINGS, OL_MAX, perm, out)
    return out


def block_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(centres (NB, 3), radii (NB,))`` float64 bounding spheres of the blocks of :data:`BLOCK` consecutive
    receivers ``points (V, 3)`` (the last block padded with its last receiver)."""
    p = np.asarray(points, dtype=np.float64)
    nb = -(-p.shape[0] // BLOCK)
    pad = nb * BLOCK - p.shape[0]
    if pad:
        p = np.concatenate([p, np.repeat(p[-1:], pad, axis=0)])
    blocks = p.reshape(nb, BLOCK, 3)
    lo, hi = blocks.min(1), blocks.max(1)
    m = 0.5 * (lo + hi)
    return m, np.sqrt(((blocks - m[:, None]) ** 2).sum(-1).max(1))


def cap_bound(block_centers: np.ndarray, block_radii: np.ndarray, centers: np.ndarray,
              radii: np.ndarray) -> np.ndarray:
    """``(NB, S)`` float64: the largest solid angle (sr) sphere ``s`` subtends from any point of block ``b``'s
    bounding sphere (``2 pi`` where that sphere may reach into it)."""
    d = np.sqrt(((block_centers[:, None, :] - np.asarray(centers, np.float64)[None]) ** 2).sum(-1))
    dmin = d - block_radii[:, None]
    r = np.asarray(radii, np.float64)[None]
    far = dmin > r
    s2 = np.where(far, (r / np.where(far, dmin, 1.0)) ** 2, 1.0)
    return 2.0 * math.pi * s2 / (1.0 + np.sqrt(1.0 - s2))  # 2 pi (1 - sqrt(1 - s2)), without the cancellation


def block_spheres(block_centers: np.ndarray, block_radii: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                  eps: float = CULL_SOLID_ANGLE) -> tuple[np.ndarray, np.ndarray]:
    """The culled sphere lists (module doc): ``(starts (NB + 1,) int64, spheres (M,) int32)``, block ``b`` keeping
    ``spheres[starts[b]:starts[b + 1]]`` (ascending), the dropped ones' caps summing to ``<= eps`` at every receiver
    of the block."""
    om = cap_bound(block_centers, block_radii, centers, radii)
    keep = np.ones(om.shape, dtype=bool)
    if eps > 0 and om.size:
        order = np.argsort(om, axis=1, kind="stable")
        drop_sorted = np.cumsum(np.take_along_axis(om, order, axis=1), axis=1) <= eps
        np.put_along_axis(keep, order, ~drop_sorted, axis=1)
    counts = keep.sum(1)
    starts = np.zeros(om.shape[0] + 1, dtype=np.int64)
    np.cumsum(counts, out=starts[1:])
    return starts, np.nonzero(keep)[1].astype(np.int32)


def spatial_order(points: np.ndarray) -> np.ndarray:
    """``(V,)`` int64 permutation putting ``points (V, 3)`` in Morton (Z-curve) order of a 1024^3 grid over their
    box, so that blocks of consecutive receivers are compact (the receivers' rest positions, once)."""
    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-12).max() * 1023).astype(np.uint64)
    code = np.zeros(p.shape[0], dtype=np.uint64)
    for bit in range(10):  # a loop over the grid's bits
        for a in range(3):
            code |= ((q[:, a] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + a)
    return np.argsort(code, kind="stable")


class CompiledShexp:
    """SHEXP visibility of one receiver set (a character's vertices, the floor's) under spheres, per frame (module
    doc).

    Args:
        tables: :class:`ShexpTables` (the run's graph's: :meth:`ShexpTables.from_graph`).
        rest_points: ``(V, 3)`` the receivers at rest (their order into blocks, :func:`spatial_order`).
        eps: the culling budget (sr, :data:`CULL_SOLID_ANGLE`; ``0``: every sphere at every receiver).
    """

    def __init__(self, tables: ShexpTables, rest_points: np.ndarray, eps: float = CULL_SOLID_ANGLE) -> None:
        rest = np.asarray(rest_points, dtype=np.float64)
        check_shape(rest, "V 3", name="shexp receivers")
        check(np.isfinite(eps) and eps >= 0, f"shexp culling budget must be >= 0 sr, got {eps}")
        self.tables = tables
        self.eps = float(eps)
        self.order = tables.order
        self.perm = spatial_order(rest) if rest.shape[0] else np.zeros(0, np.int64)
        #: the last call's kept (block, sphere) pairs and blocks with any (for the benchmark's report)
        self.stats: dict[str, int] = {}
        #: the last call's receivers (ascending indices) under some kept sphere: elsewhere the constant 1
        self.occluded = np.zeros(0, np.int64)

    def __call__(self, points: np.ndarray, frames: np.ndarray | None, centers: np.ndarray,
                 radii: np.ndarray) -> np.ndarray:
        """``(V, C)`` float32 local-frame visibility of ``points (V, 3)`` in ``frames (V, 3, 3)`` (rows t, b, n;
        ``None``: world) under spheres ``centers (S, 3)``, ``radii (S,)`` (> 0); no sphere: the constant 1."""
        p = np.asarray(points, dtype=np.float32)
        check(p.shape == (self.perm.shape[0], 3), f"shexp: {p.shape} receivers, expected ({self.perm.shape[0]}, 3)")
        c = np.ascontiguousarray(centers, dtype=np.float32)
        check_shape(c, "S 3", name="shexp sphere centres")
        r = np.ascontiguousarray(radii, dtype=np.float32)
        check_shape(r, (c.shape[0],), name="shexp sphere radii")
        if not (bool((r > 0).all()) and np.isfinite(c).all() and np.isfinite(p).all()):
            raise PrtError("shexp: sphere radii must be > 0 and every input finite")
        self.occluded = np.zeros(0, np.int64)
        if c.shape[0] == 0 or p.shape[0] == 0:
            out = np.zeros((p.shape[0], self.order ** 2), np.float32)
            out[:, 0] = math.sqrt(4 * math.pi)
            return out
        pp = p[self.perm]
        m, rho = block_bounds(pp)
        starts, spheres = block_spheres(m, rho, c, r, self.eps)
        counts = np.diff(starts)
        self.stats = {"pairs": int(spheres.shape[0]) * BLOCK, "blocks": int((counts > 0).sum()),
                      "all_blocks": int(counts.shape[0])}
        self.occluded = np.sort(self.perm[np.repeat(counts > 0, BLOCK)[:pp.shape[0]]])
        fr = None if frames is None else np.asarray(frames, np.float32)[self.perm]
        return shexp_blocks(receiver_rows(pp, fr), starts, spheres, c, r, self.perm, self.tables)
