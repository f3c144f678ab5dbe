"""Local visibility networks (issue 13): one small network shared by every vertex of a deformable subject, fed with
the vertex's neighbour offsets in its own frame, instead of a per-cluster model.

* :mod:`~prt_torch.local.models`: the networks (torch ``nn.Module``s);
* :mod:`~prt_torch.local.soa`: the neighbour-offset kernel (numba, vertex-last);
* :mod:`~prt_torch.local.fit`: the ``train.local`` stage (the fit-stage hook);
* :mod:`~prt_torch.local.graph`, :mod:`~prt_torch.local.data`: the shipped ``local.onnx`` and neighbour data (the
  export hook, and the reader the player uses);
* :mod:`~prt_torch.local.player`: the input of the shipped network for a deformable player
  (``player.sources.VISIBILITY_SOURCES``);
* :mod:`~prt_torch.local.compare`: the ``learned_local_*`` rows of ``prt compare`` (the compare hook).

The stages find these hooks through their tables (:mod:`prt_torch.plugins`); nothing in the core imports this
package. The ``train.local`` schema stays in :mod:`prt_torch.fit.config`.
"""
