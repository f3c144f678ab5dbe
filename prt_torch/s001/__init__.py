"""Seed 001's system (Sloan-style transfer matrices for animated characters): one package, every stage's hook.

* :mod:`~prt_torch.s001.bake`: per-vertex local-frame transfer matrices ``T (V, C, C)`` from the bake's own rays
  and hits (the bake-extras hook; ``bake.transfer_matrix``);
* :mod:`~prt_torch.s001.ncut`: normalized cut of the mesh into segments (eq. 3 affinity, ``(D - W) y = lambda D y``);
* :mod:`~prt_torch.s001.rcpca`: revised clustered PCA (sec. 4: incremental clusters, merging, eigenspace updates);
* :mod:`~prt_torch.s001.quantize`: 16-bit quantisation of the compressed coefficients;
* :mod:`~prt_torch.s001.fit`: the ``train.s001`` stage -> ``s001.npz`` (the fit-stage hook);
* :mod:`~prt_torch.s001.posespace`: pose-space interpolation (cKDTree nearest poses, NRBF eq. 6, eq. 7);
* :mod:`~prt_torch.s001.brdf_matrix`: the BRDF matrix ``B (C, C)`` (view SH x light SH) and its SVD factors;
* :mod:`~prt_torch.s001.shading`: eq. 5 shading ``Gamma = V^T B T L`` with the factored BRDF matrix;
* :mod:`~prt_torch.s001.player`, :mod:`~prt_torch.s001.renderer`: the run-time player (eq. 8-9, numpy) and the
  ``prt play --renderer s001|posespace`` renderer (the play hook);
* :mod:`~prt_torch.s001.compare`: the ``s001`` row of ``prt compare`` (the compare hook);
* :mod:`~prt_torch.s001.bench`: ``prt bench s001``.

The stages find these hooks through their tables (:mod:`prt_torch.plugins`); nothing in the core imports this
package. The config schemas stay with their stage (``bake.transfer_matrix``/``matrix_*`` in
:mod:`prt_torch.bake.config`, ``train.s001`` = ``S001Config`` in :mod:`prt_torch.fit.config`).
"""
