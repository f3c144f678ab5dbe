"""Seed 000's learned transfer on the real-time path (issue 12): the diffuse transfer vectors (and the subsurface
exit transfer) the bake records, learned from the pose like visibility, shipped and played.

* :mod:`~prt_torch.transfer.fit`: the ``train.transfer`` stage - the existing regressors fitted to the baked
  ``transfer`` / ``subsurface`` vectors, global output PCA (Table 1's PCA(8, 22)) or per cluster (the fit hook);
* :mod:`~prt_torch.transfer.graph`, :mod:`~prt_torch.transfer.shading`: ``transfer.onnx`` (pose -> transfer ->
  radiance, ``albedo * (L . t)``) and its parity check (the export hook);
* :mod:`~prt_torch.transfer.player`, :mod:`~prt_torch.transfer.play`: the player and ``prt play --renderer
  transfer`` (the play hook);
* :mod:`~prt_torch.transfer.compare`: the ``learned_transfer`` rows of ``prt compare`` (the compare hook).

The bake side is core: the diffuse transfer with its interreflection bounces (:mod:`prt_torch.bake.transfer`) and
the subsurface dipole (:mod:`prt_torch.bake.subsurface`) are shared with seed 001's transfer matrices and computed
by the bake's own trace (``bake.transfer``, ``bake.subsurface``). The stages find these hooks through their tables
(:mod:`prt_torch.plugins`); nothing in the core imports this package.
"""
