"""Simulated cloth subjects (issue 11): configs, the subject mesh, the MuJoCo simulation and its vertex cache.

A method package (:mod:`prt_torch.plugins`): its bake hook (:mod:`prt_torch.cloth.bake`, the deformable subject
source of ``bake.deformable.SUBJECTS``: simulate what the cache lacks, plan the cached frames, read a sequence for
``prt compare``), its export hook (:mod:`prt_torch.cloth.export`: ``deform.npz``, ``positions.onnx``), its player
(:mod:`prt_torch.cloth.player`, ``prt play --sequence``), ``prt simulate`` (:mod:`prt_torch.cloth.command`) and
``prt bench cloth``. The deformable rule itself (frames, clusters, "is this run deformable") is core
(:mod:`prt_torch.bake.deformable`, :mod:`prt_torch.deform`). MuJoCo is imported lazily inside the simulation
functions only (:mod:`prt_torch.cloth.engine`), so the rest reads caches without it.
"""
