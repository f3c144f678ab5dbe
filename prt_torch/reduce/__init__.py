"""Dimensionality reduction: input PCA, per-cluster and global output PCA, storage accounting."""

from prt_torch.reduce.output_pca import ClusterPCA, GlobalOutputPCA
from prt_torch.reduce.pca import PCA, components_for_variance
from prt_torch.reduce.storage import compact_floats, state_bytes, storage_markdown, storage_table

__all__ = ["PCA", "ClusterPCA", "GlobalOutputPCA", "compact_floats", "components_for_variance", "state_bytes",
           "storage_markdown", "storage_table"]
