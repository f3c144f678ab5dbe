"""Simulated cloth subjects (issue 11): configs, the subject mesh, the MuJoCo simulation and its vertex cache.

Rank 5 (beside :mod:`prt_torch.bake`); MuJoCo is imported lazily inside the simulation functions only
(:mod:`prt_torch.cloth.engine`), so the rest reads caches without it.
"""
