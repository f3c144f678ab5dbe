"""Reflection product operators (seed 003 sec. 4): build, save, load, and a catalogue of named RPOs.

An RPO of a BRDF holds, for ``k`` Kautz-McCool terms and SH order ``n`` (``C = n*n``):

* ``u (k, C)``: SH of the light factors ``U_b`` (sphere projection, :mod:`prt_torch.brdf.factor`);
* ``w (k, C)``: SH of the view factors ``W_b`` (least squares over the upper hemisphere);
* ``M (k, C, C)``: product matrices ``M_b = sum_k u_bk Gamma_{., ., k}`` (eq. 10);
* ``tint (3,)``: RGB scale of the BRDF shape that was factored;
* ``factor_order``: ``"before"`` or ``"after"`` the SH projection (:mod:`prt_torch.brdf.factor`; a file without the
  entry was written before the option existed: ``"before"``).

Shading (eq. 11): ``L(wo) = tint * sum_b (w_b . y(wo)) (l . (M_b v))``. The paper stores
``k n^2 (1 + n^2)`` floats (``M`` and ``w``; 2176 floats = 8704 bytes for ``k = 8``, ``n = 4``). The file
here stores only ``u`` and ``w`` (``2 k n^2`` float32) and rebuilds ``M`` on load with the Gaunt tensor
(numpy; loading never imports torch).
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prt_torch.brdf.analytic import BRDF, BlinnPhong, CookTorrance, Lambert, Phong, Ward
from prt_torch.brdf.factor import (
    DEFAULT_FACTOR_ORDER,
    DEFAULT_N_PHI,
    DEFAULT_N_THETA,
    DEFAULT_TERMS,
    check_factor_order,
    factor_sh,
    hemisphere_rule,
    sh_rule_error,
    tabulate,
)
from prt_torch.errors import DamagedArtifact, MissingArtifact, PrtError, StaleArtifact
from prt_torch.io import atomic_path
from prt_torch.sh.basis import check_order, order_from_coeffs
from prt_torch.sh.product import MAX_PRODUCT_ORDER, product_matrix

RPO_FORMAT_VERSION = 1


@dataclass
class RPO:
    """A reflection product operator (see module docstring). Arrays are float32 numpy.

    Attributes:
        M: ``(k, C, C)`` product matrices of the light factors.
        u: ``(k, C)`` light-factor SH.
        w: ``(k, C)`` view-factor SH.
        tint: ``(3,)`` RGB tint.
        order: SH order ``n``.
        name: catalogue / BRDF name.
        rel_error: relative L2 error of the ``k``-term SVD truncation of ``f~``.
        sh_rel_error: relative L2 error of the SH-projected factorisation vs ``f~`` (NaN if unknown).
        factor_order: how the factors were made (:data:`prt_torch.brdf.factor.FACTOR_ORDERS`).
        meta: build figures (not saved): ``seconds``, ``operator_error`` (vs the untruncated order-``n``
            operator, :func:`prt_torch.brdf.factor.operator_error`).
    """

    M: np.ndarray
    u: np.ndarray
    w: np.ndarray
    tint: np.ndarray
    order: int
    name: str
    rel_error: float
    sh_rel_error: float = float("nan")
    meta: dict[str, float] = field(default_factory=dict)
    factor_order: str = "before"

    @property
    def k(self) -> int:
        """Number of BRDF terms."""
        return int(self.u.shape[0])

    @property
    def paper_float_count(self) -> int:
        """Seed 003's storage count ``k n^2 (1 + n^2)`` floats (``M`` and ``w``)."""
        c = self.order * self.order
        return self.k * c * (1 + c)

    @property
    def stored_float_count(self) -> int:
        """Floats in our file: ``u`` and ``w`` (``2 k n^2``) plus the tint."""
        return int(self.u.size + self.w.size + 3)

    @classmethod
    def from_factors(cls, u: np.ndarray, w: np.ndarray, tint: np.ndarray, name: str, rel_error: float,
                     sh_rel_error: float = float("nan"), factor_order: str = "before") -> RPO:
        """Validate ``u, w (k, C)`` and build ``M`` from ``u``."""
        check_factor_order(factor_order)
        u = np.asarray(u, dtype=np.float32)
        w = np.asarray(w, dtype=np.float32)
        if u.ndim != 2 or u.shape != w.shape:
            raise PrtError(f"RPO factors u and w must both be (k, C), got {u.shape} and {w.shape}")
        order = order_from_coeffs(u.shape[1])
        check_order(order, MAX_PRODUCT_ORDER)
        if not (np.isfinite(u).all() and np.isfinite(w).all()):
            raise PrtError("RPO factors contain NaN or Inf")
        t = np.asarray(tint, dtype=np.float32).reshape(-1)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise PrtError(f"RPO tint must be a finite RGB triple, got shape {t.shape}")
        M = product_matrix(u.astype(np.float64)).astype(np.float32)
        return cls(M=M, u=u, w=w, tint=t, order=order, name=str(name), rel_error=float(rel_error),
                   sh_rel_error=float(sh_rel_error), factor_order=factor_order)

    def save(self, path: str | os.PathLike[str]) -> int:
        """Write ``u``, ``w``, ``tint`` (float32) and metadata as an uncompressed ``.npz``, atomically.

        Returns the file size in bytes.
        """
        p = Path(path)
        if p.suffix != ".npz":
            raise PrtError(f"RPO files use the .npz suffix, got {p.name}")
        with atomic_path(p) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, u=self.u.astype(np.float32), w=self.w.astype(np.float32),
                         tint=self.tint.astype(np.float32),
                         meta=np.array([RPO_FORMAT_VERSION, self.order, self.rel_error, self.sh_rel_error]),
                         name=np.array(self.name), factor_order=np.array(self.factor_order))
                f.flush()
                os.fsync(f.fileno())
        return p.stat().st_size

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> RPO:
        """Read an RPO written by :meth:`save` (numpy only; ``M`` is rebuilt from ``u``)."""
        p = Path(path)
        if not p.is_file():
            raise MissingArtifact(f"RPO file not found: {p}")
        try:
            with np.load(p, allow_pickle=False) as z:
                u, w, tint, meta, name = z["u"], z["w"], z["tint"], z["meta"], str(z["name"])
                order_by = str(z["factor_order"]) if "factor_order" in z.files else "before"
        except (KeyError, ValueError, OSError) as exc:
            raise DamagedArtifact(f"{p.name}: not an RPO file ({type(exc).__name__}: {exc})".splitlines()[0]) from None
        if meta.shape != (4,) or int(meta[0]) != RPO_FORMAT_VERSION:
            raise StaleArtifact(f"{p.name}: unsupported RPO file version")
        try:
            rpo = cls.from_factors(u, w, tint, name, float(meta[2]), float(meta[3]), order_by)
        except PrtError as exc:  # factors that do not fit together (shapes, NaN): a damaged file
            raise DamagedArtifact(str(exc)) from None
        if rpo.order != int(meta[1]):
            raise DamagedArtifact(f"{p.name}: RPO order {int(meta[1])} does not match its {u.shape[1]} coefficients")
        return rpo


def build_rpo(brdf: BRDF, order: int = 4, k: int = DEFAULT_TERMS, n_theta: int = DEFAULT_N_THETA,
              n_phi: int = DEFAULT_N_PHI, name: str | None = None, factor_order: str = DEFAULT_FACTOR_ORDER,
              quiet: bool = False) -> RPO:
    """Tabulate, factor (``k`` terms, SVD ``factor_order`` the SH projection: :func:`prt_torch.brdf.factor.factor_sh`)
    and build an :class:`RPO` of SH order ``n``.

    ``rel_error`` is the SVD truncation error (in the norm of that order), ``sh_rel_error`` the error of the
    SH-projected factorisation over (sphere of ``wi``) x (hemisphere of ``wo``); ``meta``: ``seconds`` (build time),
    ``operator_error`` (vs the untruncated order-``n`` operator). ``quiet``: no warning for ``"after"`` with ``k > C``.
    """
    check_factor_order(factor_order)
    check_order(order, MAX_PRODUCT_ORDER)
    if not isinstance(brdf, BRDF):
        raise PrtError(f"build_rpo needs a BRDF, got {type(brdf).__name__}")
    from threadpoolctl import threadpool_limits

    t0 = time.perf_counter()
    # single-threaded BLAS: the randomized SVD's small QR/LU/SVD steps run ~5x slower when BLAS threads
    # contend for busy cores (measured on the 2-core CI machine), and one core is plenty for 1152^2 tables
    with threadpool_limits(limits=1):
        dirs, wts = hemisphere_rule(n_theta, n_phi)
        table = tabulate(brdf, dirs, dirs)
        sf = factor_sh(brdf, order, k, factor_order, n_theta, n_phi, table=table, quiet=quiet)
        sh_err = sh_rule_error(dirs, wts, dirs, wts, sf.u, sf.w, table)
    rpo = RPO.from_factors(sf.u, sf.w, brdf.tint, name or brdf.name, sf.rel_error, sh_err, factor_order)
    rpo.meta["seconds"] = time.perf_counter() - t0
    rpo.meta["operator_error"] = sf.operator_error
    return rpo


#: the catalogue: name -> BRDF factory (physically normalised defaults, white tint)
CATALOGUE: dict[str, type[BRDF] | object] = {
    "lambert": lambda: Lambert(),
    "phong": lambda: Phong(exponent=16.0, kd=0.3, ks=0.7),
    "blinn": lambda: BlinnPhong(exponent=32.0, kd=0.3, ks=0.7),
    "ggx": lambda: CookTorrance(roughness=0.5, f0=0.04, kd=0.5, ks=0.5),
    "ward": lambda: Ward(alpha=0.3, kd=0.3, ks=0.7),
}


def default_cache_dir() -> Path:
    """``$PRT_CACHE`` or ``~/.cache/prt_torch``, plus ``/rpo_cache`` (built RPOs by name and settings)."""
    return Path(os.environ.get("PRT_CACHE", Path.home() / ".cache" / "prt_torch")) / "rpo_cache"


def builtin_brdf(name: str) -> BRDF:
    """A catalogue BRDF by name (``lambert``, ``phong``, ``blinn``, ``ggx``, ``ward``)."""
    if name not in CATALOGUE:
        raise PrtError(f"unknown built-in BRDF {name!r}: expected one of {', '.join(CATALOGUE)}")
    return CATALOGUE[name]()  # type: ignore[operator]


def rpo_key_text(brdf: object, order: int, k: int, factor_order: str = DEFAULT_FACTOR_ORDER) -> str:
    """The text an RPO built by :func:`build_rpo` is content-addressed by (hash it): the file format, the BRDF with
    all its parameters, ``order``, ``k``, the hemisphere rule and the factorisation order (``"before"`` adds
    nothing, so caches written before the option existed stay valid)."""
    check_factor_order(factor_order)
    text = f"{RPO_FORMAT_VERSION}:{brdf!r}:{int(order)}:{int(k)}:{DEFAULT_N_THETA}x{DEFAULT_N_PHI}"
    return text if factor_order == "before" else f"{text}:{factor_order}"


def builtin_rpo(name: str, order: int = 4, k: int = DEFAULT_TERMS, cache_dir: str | os.PathLike[str] | None = None,
                use_cache: bool = True, factor_order: str = DEFAULT_FACTOR_ORDER) -> RPO:
    """A catalogue RPO, loaded from ``cache_dir`` (default :func:`default_cache_dir`) or built (< 3 s)."""
    brdf = builtin_brdf(name)
    check_order(order, MAX_PRODUCT_ORDER)
    key = hashlib.sha256(rpo_key_text(brdf, order, k, factor_order).encode())
    path = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = path / f"{name}_n{order}_k{k}_{key.hexdigest()[:12]}.npz"
    if use_cache and path.is_file():
        try:
            return RPO.load(path)
        except (StaleArtifact, DamagedArtifact):
            pass  # a stale or damaged cache entry: rebuild it
    rpo = build_rpo(brdf, order=order, k=k, name=name, factor_order=factor_order)
    if use_cache:
        try:
            rpo.save(path)
        except OSError:
            pass  # a read-only cache is not an error
    return rpo
