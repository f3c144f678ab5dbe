"""Pose -> visibility models: regressors batched over clusters and the end-to-end module.

``VisibilityModel`` (pose ``(B, A)`` -> visibility ``(B, V, C)``), ``load_model(run_dir, kind=None)``.

The torch classes are exported lazily (module ``__getattr__``, PEP 562): ``from prt_torch.models import X`` works as
before, while importing a numpy-only submodule (``prt_torch.s001.posespace``, the seed-001 player's) runs this
package without importing torch.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.models.projection import GlobalUnprojection, InputProjection, OutputUnprojection
    from prt_torch.models.regressors import (
        REGRESSORS,
        LinearRegressor,
        MLPRegressor,
        QuadraticRegressor,
        quadratic_features,
    )
    from prt_torch.models.visibility import (
        KINDS,
        VisibilityModel,
        link_default,
        load_metadata,
        load_model,
        load_model_file,
        model_path,
        packed_state,
        save_model,
    )

#: exported name -> its submodule (imported on first access)
_LAZY: dict[str, str] = {
    **dict.fromkeys(("GlobalUnprojection", "InputProjection", "OutputUnprojection"), "projection"),
    **dict.fromkeys(("REGRESSORS", "LinearRegressor", "MLPRegressor", "QuadraticRegressor", "quadratic_features"),
                    "regressors"),
    **dict.fromkeys(("KINDS", "VisibilityModel", "link_default", "load_metadata", "load_model", "load_model_file",
                     "model_path", "packed_state", "save_model"), "visibility"),
}


def __getattr__(name: str) -> Any:
    """The torch exports, imported on first access (module docstring)."""
    sub = _LAZY.get(name)
    if sub is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    # plain imports (not importlib) so that tests/test_packaging.py sees these lazy edges
    if sub == "projection":
        import prt_torch.models.projection
    elif sub == "regressors":
        import prt_torch.models.regressors
    else:
        import prt_torch.models.visibility  # noqa: F401
    value = getattr(sys.modules[f"{__name__}.{sub}"], name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = [
    "KINDS",
    "REGRESSORS",
    "GlobalUnprojection",
    "InputProjection",
    "LinearRegressor",
    "MLPRegressor",
    "OutputUnprojection",
    "QuadraticRegressor",
    "VisibilityModel",
    "load_metadata",
    "load_model",
    "link_default",
    "load_model_file",
    "model_path",
    "packed_state",
    "quadratic_features",
    "save_model",
]
