"""Deformable (non-skeletal) meshes: mesh checks, dihedral angles, spatial clusters, vertex frames without bones.

numpy + scipy + scikit-learn only; torch lives in :mod:`prt_torch.deform.dihedral_torch` alone (the exported
graph's pre-processing), which no torch-free module imports.
"""
