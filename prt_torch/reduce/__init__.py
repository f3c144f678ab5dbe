"""Dimensionality reduction: input PCA, per-cluster and global output PCA."""

from prt_torch.reduce.output_pca import ClusterPCA, GlobalOutputPCA
from prt_torch.reduce.pca import PCA, components_for_variance

__all__ = ["PCA", "ClusterPCA", "GlobalOutputPCA", "components_for_variance"]
