"""Sphere blockers carried by bones (seed 003 section 7): fit on the rest mesh, pose with the skeleton."""

from prt_torch.blockers.spheres import SphereSet, fit_spheres, pose_spheres, vertex_bones

__all__ = ["SphereSet", "fit_spheres", "pose_spheres", "vertex_bones"]
