"""prt_torch: learned precomputed radiance transfer for animated characters.

Pipeline: rig (skinned character, clips) -> bake (Embree SH visibility) -> reduce (PCA,
clusters) -> fit (linear / quadratic / tanh-MLP regressors) -> shade (reflection product
operators under zonal-harmonic lighting) -> export (ONNX) -> play (onnxruntime + pyvista).

Conventions shared by every module are in ``docs/DESIGN.md``.
"""

from prt_torch.errors import PrtError, PrtWarning

__all__ = ["PrtError", "PrtWarning", "__version__"]
__version__ = "0.1.0"
