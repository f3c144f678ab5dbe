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

The methods of the method packages (``learned_local_*``, ``sg_vct``, ``shexp``, ``learned_transfer``, ``s001`` /
``posespace``, ...) live in their packages (``prt_torch/<package>/compare.py``) and are found through
:data:`COMPARE_METHODS`, a stage table (:mod:`prt_torch.plugins`): this package never imports a method package.

Adding a method (one small module)::

    # prt_torch/<package>/compare.py (a core method: prt_torch/compare/methods/my_method.py)
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

and list it in :data:`COMPARE_METHODS` under its package (``"prt_torch.<package>.compare:MyMethod"``; a core method:
import its module at the bottom of this file). Importing the module registers its methods; the table's order is
the display order. A ``radiance`` method returns ``{brdf: (B, V, 3)}`` from ``radiance(batch, shading)``
(``shading``: a :class:`RadianceRequest` with the lighting, the RPO names and analytic BRDFs, and the camera); its
``vis_rel_err`` is ``null``.
"""

from __future__ import annotations

import importlib

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
from prt_torch.plugins import StageTable

__all__ = ["METHODS", "CompareRun", "FrameBatch", "FrameSet", "Method", "MethodBase", "RadianceRequest", "register",
           "resolve", "unregister"]

#: method package -> its compare methods (``"prt_torch.<package>.compare:Class"``; importing the module registers
#: every method it defines, variants included). The table's order is the display order of :data:`METHODS`, between
#: the core methods ``learned*`` and ``pca_floor``.
COMPARE_METHODS: StageTable = {
    "local": ("prt_torch.local.compare:LearnedLocalLinear", "prt_torch.local.compare:LearnedLocalMlp"),
    "vct": ("prt_torch.vct.compare:SGVCT", "prt_torch.vct.compare:SGVCTNoPeak"),
    "shexp": ("prt_torch.shexp.compare:Shexp",),
    "transfer": ("prt_torch.transfer.compare:LearnedTransfer", "prt_torch.transfer.compare:BakedTransfer"),
    "s001": ("prt_torch.s001.compare:S001", "prt_torch.s001.compare:PoseSpace"),
    "heightfield": (),
    "cloth": (),
}


def _register_packages(table: StageTable) -> None:
    """Import the modules of ``table``'s references in the table's order: each registers its methods.

    The module only, not the attribute: a method package's compare module that is being imported first imports
    this package (through :mod:`~prt_torch.compare.methods.base`) and is not complete yet; its ``@register``
    decorators add its methods when it finishes (the attributes themselves are checked by
    ``tests/architecture/test_layers.py``)."""
    for refs in table.values():
        for ref in refs:
            importlib.import_module(ref.partition(":")[0])


# the built-in methods register themselves on import (display order): the core ones, then the method packages'
from prt_torch.compare.methods import sh_truth as _sh_truth  # noqa: E402,F401,I001
from prt_torch.compare.methods import unshadowed as _unshadowed  # noqa: E402,F401
from prt_torch.compare.methods import learned as _learned  # noqa: E402,F401

_register_packages(COMPARE_METHODS)

from prt_torch.compare.methods import pca_floor as _pca_floor  # noqa: E402,F401
