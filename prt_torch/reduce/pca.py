"""Principal component analysis by SVD, with retained-variance selection.

Used for the input (pose) reduction of seed 003 section 5.2, ``X = P_i (x - mean)``, and for the
output (visibility) reductions. Rows are samples: ``data (N, D)``. ``components (k, D)`` are
orthonormal rows, ``explained (min(N, D),)`` the full eigen-spectrum (variances, descending), so
plots can show it (seed 000 Fig. 4). Works on numpy float64 internally.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError, check


def _check_data(data: np.ndarray, name: str) -> np.ndarray:
    data = np.asarray(data)
    check(data.ndim == 2, f"{name}: expected a (N, D) array, got shape {data.shape}")
    check(data.shape[0] >= 2, f"{name}: need at least 2 samples, got {data.shape[0]}")
    check(bool(np.isfinite(data).all()), f"{name}: contains NaN or Inf")
    return data.astype(np.float64, copy=False)


def components_for_variance(explained: np.ndarray, variance: float) -> int:
    """Smallest ``k >= 1`` whose leading ``k`` eigenvalues hold ``variance`` of the total."""
    check(0.0 < variance <= 1.0, f"retained variance must be in (0, 1], got {variance}")
    total = float(explained.sum())
    if total <= 0.0:
        return 1
    frac = np.cumsum(explained) / total
    k = int(np.searchsorted(frac, variance - 1e-12) + 1)
    return max(1, min(k, len(explained)))


def _thin_svd(xc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``(r,)`` and right vectors ``(r, D)`` of ``xc (N, D)``.

    Wide data (``D > 2N``, e.g. a cluster's ``V_c * C`` visibility over few frames) goes through
    the ``N x N`` Gram matrix (``eigh``), 10-50x faster than LAPACK's SVD here; directions with
    singular values below ``1e-7 s_max`` (numerically null, never retained) are dropped.
    """
    n, d = xc.shape
    if d <= 2 * n:
        _, s, vt = np.linalg.svd(xc, full_matrices=False)
        return s, vt
    lam, u = np.linalg.eigh(xc @ xc.T)
    order = np.argsort(lam)[::-1]
    lam, u = np.maximum(lam[order], 0.0), u[:, order]
    s = np.sqrt(lam)
    keep = s > (s[0] * 1e-7 if s[0] > 0 else np.inf)
    keep[0] = True
    s, u = s[keep], u[:, keep]
    vt = (u.T @ xc) / np.where(s > 0, s, 1.0)[:, None]
    return s, vt


@dataclass
class PCA:
    """A fitted PCA: ``reduce(x) = ((x - mean) @ components.T) / scale``.

    ``mean (D,)``, ``components (k, D)`` orthonormal rows, ``scale (k,)``: ones, or the standard
    deviation along each component when ``whiten`` (then reduced coordinates have unit variance on
    the training data; still a linear projection). ``explained (r,)`` is the full spectrum of
    variances (``r = min(N, D)``), ``retained`` the fraction of variance the ``k`` components keep.
    """

    mean: np.ndarray
    components: np.ndarray
    scale: np.ndarray
    explained: np.ndarray
    retained: float

    @classmethod
    def fit(cls, data: np.ndarray, variance: float | None = 0.9, n_components: int | None = None,
            whiten: bool = False, name: str = "pca input", max_components: int | None = None) -> PCA:
        """Fit on ``data (N, D)`` keeping ``n_components`` or enough for ``variance`` of the total, at most
        ``max_components`` (``None``: no cap)."""
        x = _check_data(data, name)
        mean = x.mean(axis=0)
        xc = x - mean
        s, vt = _thin_svd(xc)  # eigenvalues of the covariance are s^2 / (N - 1)
        explained = s**2 / max(x.shape[0] - 1, 1)
        if n_components is None:
            check(variance is not None, "PCA needs variance or n_components")
            k = components_for_variance(explained, float(variance))
        else:
            check(1 <= n_components, f"n_components must be >= 1, got {n_components}")
            k = min(int(n_components), len(explained))
        if max_components is not None:
            check(1 <= max_components, f"max_components must be >= 1, got {max_components}")
            k = min(k, int(max_components))
        total = float(explained.sum())
        retained = float(explained[:k].sum() / total) if total > 0 else 1.0
        comps = vt[:k]
        # deterministic sign: the largest-magnitude entry of each component is positive
        idx = np.argmax(np.abs(comps), axis=1)
        signs = np.sign(comps[np.arange(k), idx])
        signs[signs == 0] = 1.0
        comps = comps * signs[:, None]
        if whiten:
            scale = np.sqrt(np.maximum(explained[:k], 1e-12 * max(total, 1e-30)))
            scale = np.where(scale > 0, scale, 1.0)
        else:
            scale = np.ones(k)
        return cls(mean=mean, components=comps, scale=scale, explained=explained, retained=retained)

    @property
    def n_components(self) -> int:
        return int(self.components.shape[0])

    @property
    def dim(self) -> int:
        return int(self.components.shape[1])

    def reduce(self, data: np.ndarray) -> np.ndarray:
        """``(N, D) -> (N, k)``."""
        x = np.asarray(data, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise PrtError(f"PCA.reduce: expected (N, {self.dim}) input, got shape {x.shape}")
        return ((x - self.mean) @ self.components.T) / self.scale

    def expand(self, reduced: np.ndarray) -> np.ndarray:
        """``(N, k) -> (N, D)``: the reconstruction ``mean + (reduced * scale) @ components``."""
        y = np.asarray(reduced, dtype=np.float64)
        if y.ndim != 2 or y.shape[1] != self.n_components:
            raise PrtError(f"PCA.expand: expected (N, {self.n_components}) input, got shape {y.shape}")
        return self.mean + (y * self.scale) @ self.components
