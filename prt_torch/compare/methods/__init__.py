"""The methods ``prt compare`` puts side by side, and the registry later methods plug into.

A method turns posed frames into either local-frame SH visibility (shaded by the harness on the shipping
path, :mod:`prt_torch.scoring`) or radiance directly. Built in:

=====================  ===========================================================================
``sh_truth``           Embree ray-traced visibility (:func:`prt_torch.bake.trace.trace_frame`, the run's
                       bake settings): the learning target, always computed (every score is against it)
``unshadowed``         the player's unoccluded hemisphere visibility (a constant)
``learned_linear``,    the run's trained models through onnxruntime (:class:`prt_torch.runtime.session.OrtGraph`):
``learned_quadratic``, the shipped ``visibility.onnx`` for the exported kind, the others' ``VisibilityGraph``
``learned_mlp``        exported into the run's compare directory
``learned_local_*``    the run's local models (``train.local``): neighbour offsets (numba) + the network in
                       onnxruntime (:mod:`prt_torch.local.compare`)
``pca_floor``          (opt-in) an oracle: the baked visibility through the model's output PCA - the error every
                       regressor with that basis has at least
=====================  ===========================================================================

Adding a method (one small module)::

    # prt_torch/compare/methods/my_method.py
    from prt_torch.compare.methods.base import FrameBatch, MethodBase, register

    @register
    class MyMethod(MethodBase):
        name = "my_method"
        output = "visibility"          # or "radiance" (then implement radiance())
        runtime = "numpy"              # what ms_per_frame times, said in the JSON

        @classmethod
        def available(cls, run) -> bool:   # run: CompareRun (run dir, dataset, character, bake settings)
            return True

        def prepare(self, run, frames) -> None:  # once, before timing (load weights, build scenes)
            ...

        def visibility(self, batch: FrameBatch):  # (B, V, C) float32 local-frame SH, timed per frame
            ...

        def bytes(self) -> int:            # run-time data beyond the character, RPOs and lighting
            return 0

and import the module at the bottom of this file (the import registers it). A ``radiance`` method returns
``{brdf: (B, V, 3)}`` from ``radiance(batch, shading)`` (``shading``: a :class:`RadianceRequest` with the
lighting, the RPO names and analytic BRDFs, and the camera); its ``vis_rel_err`` is ``null``.
"""

from __future__ import annotations

from prt_torch.compare.methods.base import (
    METHODS,
    CompareRun,
    FrameBatch,
    FrameSet,
    Method,
    MethodBase,
    RadianceRequest,
    register,
    resolve,
    unregister,
)

__all__ = ["METHODS", "CompareRun", "FrameBatch", "FrameSet", "Method", "MethodBase", "RadianceRequest", "register",
           "resolve", "unregister"]

# the built-in methods register themselves on import (display order)
from prt_torch.compare.methods import sh_truth as _sh_truth  # noqa: E402,F401,I001
from prt_torch.compare.methods import unshadowed as _unshadowed  # noqa: E402,F401
from prt_torch.compare.methods import learned as _learned  # noqa: E402,F401
from prt_torch.local import compare as _local  # noqa: E402,F401
from prt_torch.vct import compare as _sg_vct  # noqa: E402,F401
from prt_torch.shexp import compare as _shexp  # noqa: E402,F401
from prt_torch.transfer import compare as _learned_transfer  # noqa: E402,F401
from prt_torch.s001 import compare as _s001  # noqa: E402,F401
from prt_torch.compare.methods import pca_floor as _pca_floor  # noqa: E402,F401
