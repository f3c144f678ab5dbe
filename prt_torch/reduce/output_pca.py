"""Output reductions of SH visibility ``Y (F, V, C)``.

* :class:`ClusterPCA` (seed 003 section 5.2): one PCA per mesh cluster over the flattened
  ``(V_c * C)`` visibility vectors of the cluster's vertices, each keeping ``variance`` of its
  cluster's variance. Reduced outputs are returned padded to a common width ``Kmax``:
  ``(F, G, Kmax)`` with a mask ``(G, Kmax)`` of the real dimensions (``G`` clusters).
* :class:`GlobalOutputPCA` (seed 000 section 5): one PCA over per-coefficient vertex vectors:
  samples are the ``F * C`` rows ``Y[f, :, c]`` (length ``V``); each frame reduces to
  ``(C, k)`` numbers. Exposed with the same padded interface as a single group ``G = 1`` of
  width ``C * k``.

Both keep the PCA eigen-spectra (for plots) and can be truncated to another retained variance
without refitting (:meth:`ClusterPCA.truncated`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.reduce.pca import PCA, components_for_variance
from prt_torch.shapes import check_shape


def check_visibility(y: np.ndarray, name: str = "visibility") -> np.ndarray:
    """Validate ``y (F, V, C)``: finite, 3-D, ``C`` a perfect square."""
    y = np.asarray(y)
    check_shape(y, "F V C", name=name)
    c = y.shape[2]
    n = int(round(np.sqrt(c)))
    check(n * n == c and c > 0, f"{name}: last axis must be order**2 SH coefficients, got {c}")
    check(bool(np.isfinite(y).all()), f"{name}: contains NaN or Inf")
    return y


def check_clusters(cluster: np.ndarray, n_vertices: int) -> np.ndarray:
    """Validate ``cluster (V,)`` labels; returns them relabelled to ``0..G-1`` (int64)."""
    cluster = np.asarray(cluster)
    check_shape(cluster, (n_vertices,), name="cluster labels")
    check(np.issubdtype(cluster.dtype, np.integer), f"cluster: expected integer labels, got {cluster.dtype}")
    _, relabelled = np.unique(cluster, return_inverse=True)
    return relabelled.astype(np.int64)


@dataclass
class ClusterPCA:
    """Per-cluster output PCA.

    ``mean (V, C)``; ``members[g]`` the vertex indices of cluster ``g`` (ascending);
    ``pcas[g]`` a :class:`PCA` over ``(V_g * C)`` vectors laid out vertex-major
    (``Y[:, members[g], :].reshape(F, -1)``); ``variance`` the retained-variance target.
    """

    n_vertices: int
    n_coeffs: int
    members: list[np.ndarray]
    pcas: list[PCA]
    variance: float

    @classmethod
    def fit(cls, y: np.ndarray, cluster: np.ndarray, variance: float = 0.95,
            max_components: int | None = None) -> ClusterPCA:
        """Fit on training visibility ``y (F, V, C)`` with vertex labels ``cluster (V,)``; ``max_components``:
        at most this many components per cluster (the model's size: ``V C k`` basis weights)."""
        y = check_visibility(y)
        f, v, c = y.shape
        labels = check_clusters(cluster, v)
        check(0.0 < variance <= 1.0, f"output variance must be in (0, 1], got {variance}")
        members = [np.flatnonzero(labels == g) for g in range(int(labels.max()) + 1)]
        pcas = [PCA.fit(y[:, m, :].reshape(f, -1), variance=variance, name=f"visibility of cluster {g}")
                for g, m in enumerate(members)]
        out = cls(n_vertices=v, n_coeffs=c, members=members, pcas=pcas, variance=float(variance))
        return out if max_components is None else out.truncated(variance, max_components)

    @property
    def n_groups(self) -> int:
        return len(self.members)

    @property
    def dims(self) -> np.ndarray:
        """``(G,)`` retained components per cluster."""
        return np.array([p.n_components for p in self.pcas], dtype=np.int64)

    @property
    def width(self) -> int:
        """``Kmax``: the padded reduced width."""
        return int(self.dims.max())

    @property
    def mask(self) -> np.ndarray:
        """``(G, Kmax)`` bool: which padded reduced dimensions are real."""
        return np.arange(self.width)[None, :] < self.dims[:, None]

    @property
    def mean(self) -> np.ndarray:
        """``(V, C)`` training mean."""
        out = np.zeros((self.n_vertices, self.n_coeffs))
        for m, p in zip(self.members, self.pcas, strict=True):
            out[m] = p.mean.reshape(len(m), self.n_coeffs)
        return out

    def truncated(self, variance: float, max_components: int | None = None) -> ClusterPCA:
        """The same fit keeping ``variance`` of each cluster's variance instead, and at most ``max_components``
        components per cluster."""
        check(max_components is None or int(max_components) >= 1,
              f"output max_components must be >= 1, got {max_components}")
        pcas = []
        for p in self.pcas:
            k = components_for_variance(p.explained, variance)
            k = k if max_components is None else min(k, int(max_components))
            if k > p.n_components:
                raise PrtError(f"cannot raise retained variance above the fitted {self.variance} without refitting")
            total = float(p.explained.sum())
            pcas.append(replace(p, components=p.components[:k], scale=p.scale[:k],
                                retained=float(p.explained[:k].sum() / total) if total > 0 else 1.0))
        return replace(self, pcas=pcas, variance=float(variance))

    def reduce(self, y: np.ndarray) -> np.ndarray:
        """``(F, V, C) -> (F, G, Kmax)`` (zeros in padded slots)."""
        y = check_visibility(y)
        check_shape(y, ("F", self.n_vertices, self.n_coeffs), name="visibility")
        f = y.shape[0]
        out = np.zeros((f, self.n_groups, self.width))
        for g, (m, p) in enumerate(zip(self.members, self.pcas, strict=True)):
            out[:, g, : p.n_components] = p.reduce(y[:, m, :].reshape(f, -1))
        return out

    def expand(self, z: np.ndarray) -> np.ndarray:
        """``(F, G, Kmax) -> (F, V, C)``."""
        z = np.asarray(z, dtype=np.float64)
        check_shape(z, ("F", self.n_groups, self.width), name="reduced visibility")
        f = z.shape[0]
        out = np.zeros((f, self.n_vertices, self.n_coeffs))
        for g, (m, p) in enumerate(zip(self.members, self.pcas, strict=True)):
            out[:, m, :] = p.expand(z[:, g, : p.n_components]).reshape(f, len(m), self.n_coeffs)
        return out

    def padded_basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrays for a gather-only unprojection (see :class:`prt_torch.models.OutputUnprojection`).

        Returns ``basis (G, Kmax, Lmax)`` (``Lmax = max V_g * C``; each cluster's components times
        their scale, zero padded), ``gather (V * C,)`` int64 indices into the flattened
        ``(G * Lmax)`` per-cluster outputs giving vertex-major ``(V, C)`` order, and
        ``mean (V * C,)``.
        """
        c = self.n_coeffs
        lmax = max(len(m) for m in self.members) * c
        basis = np.zeros((self.n_groups, self.width, lmax))
        gather = np.zeros(self.n_vertices * c, dtype=np.int64)
        for g, (m, p) in enumerate(zip(self.members, self.pcas, strict=True)):
            basis[g, : p.n_components, : len(m) * c] = p.components * p.scale[:, None]
            flat = (m[:, None] * c + np.arange(c)[None, :]).reshape(-1)
            gather[flat] = g * lmax + np.arange(len(m) * c)
        return basis, gather, self.mean.reshape(-1)

    def compact_floats(self) -> int:
        """Numbers a packed store needs: the mean plus each cluster's real basis."""
        return self.n_vertices * self.n_coeffs + int(sum(p.components.size for p in self.pcas))


@dataclass
class GlobalOutputPCA:
    """Seed 000 section 5: one PCA over per-coefficient vertex vectors ``Y[f, :, c]`` (length V)."""

    n_vertices: int
    n_coeffs: int
    pca: PCA
    variance: float

    @classmethod
    def fit(cls, y: np.ndarray, variance: float = 0.95) -> GlobalOutputPCA:
        y = check_visibility(y)
        f, v, c = y.shape
        rows = np.transpose(y, (0, 2, 1)).reshape(f * c, v)
        return cls(n_vertices=v, n_coeffs=c, pca=PCA.fit(rows, variance=variance, name="visibility"),
                   variance=float(variance))

    @property
    def n_groups(self) -> int:
        return 1

    @property
    def width(self) -> int:
        return self.n_coeffs * self.pca.n_components

    @property
    def dims(self) -> np.ndarray:
        return np.array([self.width], dtype=np.int64)

    @property
    def mask(self) -> np.ndarray:
        return np.ones((1, self.width), dtype=bool)

    def reduce(self, y: np.ndarray) -> np.ndarray:
        """``(F, V, C) -> (F, 1, C * k)``."""
        y = check_visibility(y)
        f, v, c = y.shape
        check((v, c) == (self.n_vertices, self.n_coeffs), f"visibility: expected (F, {self.n_vertices}, "
              f"{self.n_coeffs}), got {y.shape}")
        rows = np.transpose(y, (0, 2, 1)).reshape(f * c, v)
        return self.pca.reduce(rows).reshape(f, 1, self.width)

    def expand(self, z: np.ndarray) -> np.ndarray:
        """``(F, 1, C * k) -> (F, V, C)``."""
        z = np.asarray(z, dtype=np.float64)
        f = z.shape[0]
        rows = self.pca.expand(z.reshape(f * self.n_coeffs, -1))
        return np.transpose(rows.reshape(f, self.n_coeffs, self.n_vertices), (0, 2, 1))

    def compact_floats(self) -> int:
        return int(self.pca.mean.size + self.pca.components.size)
